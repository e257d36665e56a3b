"""docs/your_problem.md's Python blocks run as the page shows them (with fewer steps), so the page cannot rot."""

import ast
import os
import re
import subprocess
import sys

from helpers import REPO

PAGE = os.path.join(REPO, "docs", "your_problem.md")


def python_blocks() -> list[str]:
    with open(PAGE, encoding="utf-8") as f:
        return re.findall(r"```python\n(.*?)```", f.read(), flags=re.S)


def run_block(code: str, cwd) -> str:
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=cwd, timeout=600,
                            env={**os.environ, "PYTHONPATH": REPO})
    assert result.returncode == 0, result.stderr
    return result.stdout


def printed(output: str, label: str):
    line = next(line for line in output.splitlines() if line.startswith(label))
    return line[len(label):].strip()


def test_the_page_has_its_two_examples():
    blocks = python_blocks()
    assert len(blocks) == 2 and "ULTHO(" in blocks[0] and "ULTHOCallback(" in blocks[1]


def test_the_ppo_loop_credits_each_choice_once_and_puts_the_learning_rate_into_the_optimizer(tmp_path):
    code = python_blocks()[0]
    assert "NUM_ITERATIONS = 4, 128, 100" in code
    output = run_block(code.replace("NUM_ITERATIONS = 4, 128, 100", "NUM_ITERATIONS = 4, 128, 5"), tmp_path)
    counts = ast.literal_eval(printed(output, "chosen and credited:"))
    assert sum(map(sum, counts.values())) == 4  # five choices, the last one not yet credited
    settings, lr = printed(output, "settings in force:").split(" optimizer lr: ")
    assert ast.literal_eval(settings)["learning_rate"] == float(lr)
    assert "iteration 0: mean return" in output


def test_the_sb3_route_runs(tmp_path):
    code = python_blocks()[1]
    assert "model.learn(100_000" in code
    output = run_block(code.replace("model.learn(100_000", "model.learn(1_536"), tmp_path)
    counts, in_force = output.strip().split("} {")
    assert sum(map(sum, ast.literal_eval(counts + "}").values())) == 2  # three rollouts: two credits
    assert set(ast.literal_eval("{" + in_force)) == {"learning_rate", "batch_size"}
    assert (tmp_path / "runs").is_dir()  # SB3's TensorBoard run, where the ultho/* tags go

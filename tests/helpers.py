"""What the script tests share: running a script as a user would, and reading back what it wrote."""

import json
import os
import signal
import subprocess
import sys
import time

from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(script: str, *args: str, timeout: float = 600) -> subprocess.CompletedProcess:
    """`python <script> <args>` from the repository root, output captured."""
    return subprocess.run([sys.executable, os.path.join(REPO, script), *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO)


def run_concurrently(script: str, arg_lists: list[list[str]], timeout: float = 600) -> list[subprocess.CompletedProcess]:
    """`run` for every argument list at once (each start pays the torch import); results in the same order."""
    processes = [subprocess.Popen([sys.executable, os.path.join(REPO, script), *args], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, cwd=REPO) for args in arg_lists]
    results = []
    for args, process in zip(arg_lists, processes):
        stdout, stderr = process.communicate(timeout=timeout)
        results.append(subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr))
    return results


def run_ok(script: str, *args: str) -> subprocess.CompletedProcess:
    result = run(script, *args)
    assert result.returncode == 0, f"{script} failed:\n{result.stdout}\n{result.stderr}"
    return result


def kill_after_first_checkpoint(script: str, run_dir: str, *args: str, timeout: float = 300) -> None:
    """Starts a run and SIGKILLs it as soon as its first checkpoint is on disk (a crash, not a clean exit)."""
    process = subprocess.Popen([sys.executable, os.path.join(REPO, script), *args], cwd=REPO,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + timeout
    path = os.path.join(run_dir, "checkpoint.pt")
    while not os.path.exists(path) and process.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait()


def summary(run_dir: str) -> dict:
    with open(os.path.join(run_dir, "summary.json")) as f:
        return json.load(f)


def scalars(run_dir: str) -> dict[str, list[tuple[int, float]]]:
    """Every scalar series in the run's TensorBoard event files, read with tensorboard's own reader."""
    accumulator = EventAccumulator(run_dir, size_guidance={"scalars": 0})
    accumulator.Reload()
    return {tag: [(e.step, e.value) for e in accumulator.Scalars(tag)] for tag in accumulator.Tags()["scalars"]}


def files_under(path: str) -> list[str]:
    return [os.path.join(d, f) for d, _, files in os.walk(path) for f in files] if os.path.exists(path) else []

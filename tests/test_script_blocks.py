"""The experiment scripts stay one file each, so the blocks they share are repeated on purpose: this test keeps the
copies identical (a change to one copy fails here, naming the block and the files) and keeps every script's layout
CleanRL's: Args, the Agent, then main, the algorithm; all bookkeeping after it, under one marked banner."""

import ast
import importlib
import os

import pytest

from helpers import REPO

PPO_SCRIPTS = ("ppo_ultho_minigrid.py", "ppo_ultho_atari.py", "ppo_ultho_procgen.py", "ppo_ultho_pybullet.py")
SAC_SCRIPT = "sac_ultho_dmc.py"
BANNER = "# ---- Bookkeeping: input, checkpoints, logging, summary (not the algorithm) ----"

# Top-level functions and classes (and the `if __name__ == "__main__":` block, as MAIN_GUARD) that must read the same
# in every PPO script, and those that sac_ultho_dmc.py shares with them.
MAIN_GUARD = "__main__"
WATCHING_BLOCKS = ("evaluated_args", "check_output_options", "wandb_logged_in", "start_tracking", "stop_tracking",
                   "video_path", "write_video", "log_video", "report_evaluation")
PPO_BLOCKS = ("Settings", "layer_init", "UsageError", "parse_args", "checked_search_space", "check_setting",
              "resumed_args", "load_checkpoint",
              "is_run_of_this_script", "restore", "rng_state", "restore_rng", "open_run_dir", "save_checkpoint",
              "stop_non_finite", "log_iteration", "log_bandit", "report_progress", "atomic_write_bytes",
              "atomic_save_json", *WATCHING_BLOCKS, MAIN_GUARD)
SAC_BLOCKS = ("UsageError", "parse_args", "resumed_args", "load_checkpoint", "is_run_of_this_script", "open_run_dir",
              "stop_non_finite", "report_progress", "atomic_write_bytes", "atomic_save_json", *WATCHING_BLOCKS,
              MAIN_GUARD)

# What each script's bookkeeping section holds at least (after the banner, in any order).
BOOKKEEPING = ("UsageError", "parse_args", "validate", "check_setting", "checked_search_space", "load_checkpoint",
               "is_run_of_this_script", "resumed_args", "restore", "save_checkpoint", "stop_non_finite",
               "log_iteration", "write_summary", "atomic_write_bytes", "atomic_save_json")
SAC_BOOKKEEPING = ("UsageError", "parse_args", "validate", "check_setting", "checked_search_space", "load_checkpoint",
                   "is_run_of_this_script", "resumed_args", "save_checkpoint", "stop_non_finite", "write_summary",
                   "atomic_write_bytes", "atomic_save_json")


def source(script: str) -> str:
    with open(os.path.join(REPO, script), encoding="utf-8") as f:
        return f.read()


def blocks(script: str) -> dict[str, tuple[int, str]]:
    """{name: (line, source text)} of the script's top-level functions and classes and its main guard."""
    text = source(script)
    found = {}
    for node in ast.parse(text).body:
        if isinstance(node, (ast.FunctionDef, ast.ClassDef)):
            name = node.name
        elif isinstance(node, ast.If) and "__name__" in ast.unparse(node.test):
            name = MAIN_GUARD
        else:
            continue
        decorators = "".join(f"@{ast.get_source_segment(text, d)}\n" for d in getattr(node, "decorator_list", []))
        found[name] = (node.lineno, decorators + ast.get_source_segment(text, node, padded=True))
    return found


def differing(block: str, scripts: tuple[str, ...]) -> list[str]:
    """The scripts whose copy of the block differs from the first script's (or which lack it)."""
    first = blocks(scripts[0]).get(block)
    assert first is not None, f"{scripts[0]} has no {block}"
    return [script for script in scripts[1:] if blocks(script).get(block, (0, None))[1] != first[1]]


@pytest.mark.parametrize("block", PPO_BLOCKS)
def test_the_ppo_scripts_share_the_block_verbatim(block):
    drifted = differing(block, PPO_SCRIPTS)
    assert not drifted, (f"{block} differs between {PPO_SCRIPTS[0]} and {', '.join(drifted)}: the copies are kept "
                         "identical on purpose; make the same change in every PPO script")


def summary_literal(script: str) -> tuple[str, ast.Dict]:
    """The script's text and the summary dict that its write_summary builds."""
    text = source(script)
    function = next(node for node in ast.parse(text).body
                    if isinstance(node, ast.FunctionDef) and node.name == "write_summary")
    return text, next(node.value for node in ast.walk(function) if isinstance(node, ast.Assign)
                      and [getattr(target, "id", None) for target in node.targets] == ["summary"])


def shared_entries(literals: dict[str, tuple[str, ast.Dict]]) -> dict[str, list[tuple[str, str]]]:
    """For each script, (key, value's source) of the keys that every script's dict has, in the script's order; a
    value that is a dict in every script is reduced the same way (its shared keys only)."""
    common = set.intersection(*({key.value for key in literal.keys} for _, literal in literals.values()))
    shared: dict[str, list[tuple[str, str]]] = {script: [] for script in literals}
    for script, (text, literal) in literals.items():
        for key, value in zip(literal.keys, literal.values):
            if key.value not in common:
                continue
            nested = {other: (other_text, dict(zip((k.value for k in other_literal.keys), other_literal.values))
                              [key.value]) for other, (other_text, other_literal) in literals.items()}
            if all(isinstance(node, ast.Dict) for _, node in nested.values()):
                shown = repr(shared_entries(nested)[script])
            else:
                shown = ast.get_source_segment(text, value)
            shared[script].append((key.value, shown))
    return shared


def test_the_summaries_share_their_common_keys_in_one_order_and_computed_alike():
    # Each benchmark adds its own keys (ALE's human-normalized score, Procgen's train and test scores and test
    # levels); the keys every PPO script writes come in the same order and are computed by the same expression.
    shared = shared_entries({script: summary_literal(script) for script in PPO_SCRIPTS})
    first = PPO_SCRIPTS[0]
    for script in PPO_SCRIPTS[1:]:
        for (key, value), (other_key, other_value) in zip(shared[first], shared[script]):
            assert (key, value) == (other_key, other_value), (
                f"summary.json's {key!r} differs between {first} ({value}) and {script} ({other_key}: "
                f"{other_value}) in write_summary: keep the shared keys in one order, computed alike")
    for key in ("final_score", "rollout_seconds", "update_seconds", "peak_rss_mb", "peak_cuda_mb", "eval",
                "settings_in_force", "bandit", "diverged"):
        assert key in dict(shared[first]), f"{key!r} is not written by every PPO script's write_summary"
    # What the tools read of every summary, SAC's included: a diverged run is a finished run that says so.
    sac_keys = {key.value for key in summary_literal(SAC_SCRIPT)[1].keys}
    assert {"final_score", "eval", "bandit", "diverged"} <= sac_keys


@pytest.mark.parametrize("block", SAC_BLOCKS)
def test_the_sac_script_shares_the_common_blocks_verbatim(block):
    drifted = differing(block, (PPO_SCRIPTS[0], SAC_SCRIPT))
    assert not drifted, (f"{block} differs between {PPO_SCRIPTS[0]} and {SAC_SCRIPT}: the copies are kept identical "
                         "on purpose; make the same change in every script")


def assert_bookkeeping_after_main(script: str, bookkeeping: tuple[str, ...]) -> dict[str, tuple[int, str]]:
    found = blocks(script)
    lines = source(script).splitlines()
    assert lines.count(BANNER) == 1, f"{script}: the bookkeeping banner must appear once: {BANNER}"
    banner = lines.index(BANNER) + 1
    assert found["main"][0] < banner, f"{script}: main must come before the bookkeeping banner"
    misplaced = [name for name in bookkeeping if found.get(name, (0,))[0] < banner]
    assert not misplaced, f"{script}: {', '.join(misplaced)} must be defined after the bookkeeping banner"
    assert found[MAIN_GUARD][0] == max(line for line, _ in found.values()), f"{script}: the main guard comes last"
    return found


@pytest.mark.parametrize("script", PPO_SCRIPTS)
def test_the_script_reads_as_the_algorithm_then_its_bookkeeping(script):
    found = assert_bookkeeping_after_main(script, BOOKKEEPING)
    order = [(name, found[name][0]) for name in ("Args", "Agent", "main") if name in found]
    assert [name for name, _ in order] == ["Args", "Agent", "main"], f"{script}: Args, Agent and main are all needed"
    assert sorted(order, key=lambda item: item[1]) == order, f"{script}: the order must be Args, Agent, main"


def test_the_sac_script_reads_as_the_algorithm_then_its_bookkeeping():
    found = assert_bookkeeping_after_main(SAC_SCRIPT, SAC_BOOKKEEPING)
    order = [found[name][0] for name in ("Args", "SAC", "sac_update", "main")]
    assert order == sorted(order), f"{SAC_SCRIPT}: the order must be Args, the learner (SAC, sac_update), main"


@pytest.mark.parametrize("script", (*PPO_SCRIPTS, SAC_SCRIPT))
def test_the_settings_in_force_hold_exactly_the_tunable_names(script):
    tree = ast.parse(source(script))
    tunable = next(ast.literal_eval(node.value) for node in tree.body if isinstance(node, ast.Assign)
                   and [target.id for target in node.targets if isinstance(target, ast.Name)] == ["TUNABLE"])
    settings = next(node for node in tree.body if isinstance(node, ast.ClassDef) and node.name == "Settings")
    fields = tuple(item.target.id for item in settings.body if isinstance(item, ast.AnnAssign))
    assert fields == tunable, f"{script}: Settings' fields {fields} are not TUNABLE {tunable}, in its order"


@pytest.mark.parametrize("script", (*PPO_SCRIPTS, SAC_SCRIPT))
def test_torch_threads_zero_means_torchs_default_and_a_negative_count_is_refused(script, tmp_path):
    module = importlib.import_module(script.removesuffix(".py"))
    runs = ["--runs-dir", str(tmp_path), "--run-name", "never-written"]
    module.validate(module.parse_args(["--torch-threads", "0", *runs]))
    with pytest.raises(module.UsageError, match=r"^--torch-threads must be >= 0 \(0: one per core\), got -1$"):
        module.validate(module.parse_args(["--torch-threads", "-1", *runs]))
    assert not os.listdir(tmp_path)

"""The experiment scripts stay one file each, so the blocks they share are repeated on purpose: this test keeps the
copies identical (a change to one copy fails here, naming the block and the files) and keeps every script's layout
CleanRL's: Args, the Agent, then main, the algorithm; all bookkeeping after it, under one marked banner."""

import ast
import os

import pytest

from helpers import REPO

PPO_SCRIPTS = ("ppo_ultho_minigrid.py", "ppo_ultho_atari.py", "ppo_ultho_procgen.py", "ppo_ultho_pybullet.py")
SAC_SCRIPT = "sac_ultho_dmc.py"
BANNER = "# ---- Bookkeeping: input, checkpoints, logging, summary (not the algorithm) ----"

# Top-level functions and classes (and the `if __name__ == "__main__":` block, as MAIN_GUARD) that must read the same
# in every PPO script, and those that sac_ultho_dmc.py shares with them.
MAIN_GUARD = "__main__"
PPO_BLOCKS = ("Settings", "UsageError", "parse_args", "checked_search_space", "resumed_args", "load_checkpoint",
              "is_run_of_this_script", "restore", "rng_state", "restore_rng", "open_run_dir", "save_checkpoint",
              "stop_non_finite", "log_iteration", "log_bandit", "report_progress", "atomic_write_bytes",
              "atomic_save_json", MAIN_GUARD)
SAC_BLOCKS = ("UsageError", "parse_args", "resumed_args", "load_checkpoint", "is_run_of_this_script", "open_run_dir",
              "stop_non_finite", "report_progress", "atomic_write_bytes", "atomic_save_json", MAIN_GUARD)

# What each PPO script's bookkeeping section holds at least (after the banner, in any order).
BOOKKEEPING = ("UsageError", "parse_args", "validate", "check_setting", "checked_search_space", "load_checkpoint",
               "is_run_of_this_script", "resumed_args", "restore", "save_checkpoint", "stop_non_finite",
               "log_iteration", "write_summary", "atomic_write_bytes", "atomic_save_json")


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
        found[name] = (node.lineno, ast.get_source_segment(text, node, padded=True))
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


@pytest.mark.parametrize("block", SAC_BLOCKS)
def test_the_sac_script_shares_the_common_blocks_verbatim(block):
    drifted = differing(block, (PPO_SCRIPTS[0], SAC_SCRIPT))
    assert not drifted, (f"{block} differs between {PPO_SCRIPTS[0]} and {SAC_SCRIPT}: the copies are kept identical "
                         "on purpose; make the same change in every script")


@pytest.mark.parametrize("script", PPO_SCRIPTS)
def test_the_script_reads_as_the_algorithm_then_its_bookkeeping(script):
    found = blocks(script)
    lines = source(script).splitlines()
    assert lines.count(BANNER) == 1, f"{script}: the bookkeeping banner must appear once: {BANNER}"
    banner = lines.index(BANNER) + 1
    order = [(name, found[name][0]) for name in ("Args", "Agent", "main") if name in found]
    assert [name for name, _ in order] == ["Args", "Agent", "main"], f"{script}: Args, Agent and main are all needed"
    assert sorted(order, key=lambda item: item[1]) == order, f"{script}: the order must be Args, Agent, main"
    assert found["main"][0] < banner, f"{script}: main must come before the bookkeeping banner"
    misplaced = [name for name in BOOKKEEPING if found.get(name, (0,))[0] < banner]
    assert not misplaced, f"{script}: {', '.join(misplaced)} must be defined after the bookkeeping banner"
    assert found[MAIN_GUARD][0] == max(line for line, _ in found.values()), f"{script}: the main guard comes last"

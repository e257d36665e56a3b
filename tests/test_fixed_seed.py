"""Refactoring must not change what a script computes: each script's short fixed-seed run is repeated with the
scripts as they were at its reference commit and must give the same summary, TensorBoard scalars and checkpoint
(weights, optimizer, bandit, environments, random-number state), bit for bit, except for times and paths.

When a commit changes what a script computes on purpose, the next commit moves the cases it changes to it in
MOVED and says why (a commit cannot name itself)."""

import io
import math
import os
import pickle
import subprocess
import sys

import gymnasium as gym

import numpy as np
import pytest
import torch

from helpers import REPO, scalars, summary

# The scripts' behaviour as of the PyBullet study's stage 1 (the runs in results/pybullet were computed by it).
REFERENCE = "0a2b7f9e61b5a16a8857c4fdb637f86f44a9eb7a"
# The cases a later commit changed on purpose, each compared with the scripts as of that commit.
MOVED = {
    # Procgen's reward normalizer zeroes a finished episode's return after normalizing its last reward.
    "procgen": "41be60e5a93018f91d8bfa7d00df1bca672ab685",
    # The evaluation samples its actions from a generator of its own (--evaluate repeats it; recording a video
    # changes nothing in training), so MiniGrid's, ALE's and PyBullet's evaluation returns changed; their training
    # did not (compared with the evaluation left out: equal, checkpoints included). Before, ALE's evaluation seeds
    # had come to be drawn from the run's seed (9a9306c).
    "minigrid": "6c3a3555fc247feb345cb830519ebaf30b1eaad1",
    "atari": "6c3a3555fc247feb345cb830519ebaf30b1eaad1",
    "atari-bf16": "6c3a3555fc247feb345cb830519ebaf30b1eaad1",
    "pybullet": "6c3a3555fc247feb345cb830519ebaf30b1eaad1",
}

CASES = {
    "minigrid": ("ppo_ultho_minigrid.py", ["--num-envs", "8", "--num-steps", "64", "--total-timesteps", "2048",
                                           "--checkpoint-every", "2", "--eval-episodes", "2", "--ultho-c", "0.5"]),
    "atari": ("ppo_ultho_atari.py", ["--env-id", "Qbert", "--num-envs", "4", "--num-steps", "128",
                                     "--total-timesteps", "1536", "--eval-episodes", "1"]),
    "atari-bf16": ("ppo_ultho_atari.py", ["--env-id", "Qbert", "--num-envs", "4", "--num-steps", "128",
                                          "--total-timesteps", "1024", "--eval-episodes", "1", "--precision", "bf16"]),
    "procgen": ("ppo_ultho_procgen.py", ["--num-envs", "4", "--num-steps", "32", "--minibatch-size", "64",
                                         "--update-chunk", "48", "--total-timesteps", "384", "--eval-episodes", "2",
                                         "--ultho-clusters", "learning_rate", "minibatch_size=32,64,128", "vf_coef"]),
    "pybullet": ("ppo_ultho_pybullet.py", ["--env-id", "HopperBulletEnv-v0", "--num-steps", "256",
                                           "--total-timesteps", "768", "--update-epochs", "2", "--eval-episodes", "2"]),
    "sac": ("sac_ultho_dmc.py", ["--env-id", "cheetah-run", "--total-timesteps", "900", "--ultho-interval", "100",
                                 "--learning-starts", "300", "--batch-size", "32", "--ultho-c", "1",
                                 "--eval-episodes", "1"]),
}

# What may differ between two runs of the same computation: how long it took, where it was written.
VOLATILE = ("run_dir", "runs_dir", "wall_time_s", "sps", "elapsed", "ultho_share")
VOLATILE_TAGS = ("charts/SPS", "charts/ultho_share")


def volatile(key: str) -> bool:
    return key in VOLATILE or key.endswith("_seconds") or key.startswith("peak_")


def reference_tree(tmp_path, commit: str) -> str:
    """The repository's files at ``commit``, unpacked beside the test's runs."""
    if subprocess.run(["git", "-C", REPO, "cat-file", "-e", f"{commit}^{{commit}}"],
                      capture_output=True).returncode != 0:
        pytest.skip(f"commit {commit[:7]} is not in this clone's history (a shallow clone)")
    tree = tmp_path / "reference"
    tree.mkdir()
    archive = subprocess.run(["git", "-C", REPO, "archive", commit], capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(tree)], input=archive, check=True)
    return str(tree)


class SpacesAsTheirDescription(pickle.Pickler):
    """Re-pickles a pickled environment with each gymnasium space replaced by its description: a space seeds its own
    generator from the operating system unless told otherwise, and none of the scripts samples from one."""

    def reducer_override(self, obj):
        return (str, (repr(obj),)) if isinstance(obj, gym.Space) else NotImplemented


class ScriptName:
    """Stands in for a function of the script that pickled the environments (its ``__main__``)."""

    def __init__(self, name: str):
        self.name = name

    def __call__(self, *args, **kwargs):
        raise AssertionError(f"{self.name} is only a name here")

    def __reduce__(self):
        return str, (f"__main__.{self.name}",)


class ScriptNamesUnpickler(pickle.Unpickler):
    def find_class(self, module, name):
        return ScriptName(name) if module == "__main__" else super().find_class(module, name)


def without_space_generators(pickled: bytes) -> bytes:
    """A pickle's bytes with the spaces' generators left out; other bytes (Procgen's saved states) as they are."""
    if not pickled.startswith(b"\x80"):
        return pickled
    buffer = io.BytesIO()
    SpacesAsTheirDescription(buffer).dump(ScriptNamesUnpickler(io.BytesIO(pickled)).load())
    return buffer.getvalue()


def assert_same(reference, current, where: str) -> None:
    """Exact equality of nested checkpoint/summary values; float NaNs equal each other."""
    if isinstance(reference, dict):
        kept = {k for k in reference if not volatile(str(k))}
        missing = kept - set(current)
        assert not missing, f"{where}: {sorted(map(str, missing))} no longer written"
        for key in kept:
            assert_same(reference[key], current[key], f"{where}.{key}")
    elif isinstance(reference, (list, tuple)):
        assert len(reference) == len(current), f"{where}: length {len(current)} != {len(reference)}"
        for k, (a, b) in enumerate(zip(reference, current)):
            assert_same(a, b, f"{where}[{k}]")
    elif isinstance(reference, torch.Tensor):
        torch.testing.assert_close(current, reference, rtol=0, atol=0, equal_nan=True, msg=where)
    elif isinstance(reference, np.ndarray):
        assert reference.dtype == current.dtype, where
        np.testing.assert_array_equal(reference, current, err_msg=where)
    elif isinstance(reference, bytes):
        assert without_space_generators(reference) == without_space_generators(current), f"{where}: pickles differ"
    elif isinstance(reference, float) and math.isnan(reference):
        assert isinstance(current, float) and math.isnan(current), f"{where}: {current} != nan"
    else:
        assert reference == current, f"{where}: {current!r} != {reference!r}"


@pytest.mark.parametrize("case", sorted(CASES))
def test_fixed_seed_run_is_the_same_as_at_the_reference_commit(tmp_path, case):
    script, args = CASES[case]
    tree = reference_tree(tmp_path, MOVED.get(case, REFERENCE))
    runs = {"reference": str(tmp_path / "old"), "current": str(tmp_path / "new")}
    common = [*args, "--seed", "3", "--torch-threads", "1", "--quiet", "--run-name", "run"]
    # Both at once; the reference's copy of the script runs in its own tree, so it imports that tree's bandit.
    processes = {side: subprocess.Popen([sys.executable, os.path.join(root, script), *common, "--runs-dir", runs[side]],
                                        cwd=root, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
                 for side, root in (("reference", tree), ("current", REPO))}
    for side, process in processes.items():
        _, stderr = process.communicate(timeout=600)
        assert process.returncode == 0, f"{side} run failed:\n{stderr}"
    reference_dir, current_dir = (os.path.join(runs[side], "run") for side in ("reference", "current"))

    assert_same(summary(reference_dir), summary(current_dir), "summary")
    reference_scalars, current_scalars = scalars(reference_dir), scalars(current_dir)
    for tag in set(reference_scalars) - set(VOLATILE_TAGS):
        assert tag in current_scalars, f"tag {tag} no longer written"
        assert_same(reference_scalars[tag], current_scalars[tag], f"tag {tag}")
    reference_checkpoint, current_checkpoint = (
        torch.load(os.path.join(d, "checkpoint.pt"), weights_only=False) for d in (reference_dir, current_dir))
    config = {k: v for k, v in reference_checkpoint.pop("config").items() if not volatile(k)}
    assert_same(config, current_checkpoint.pop("config"), "checkpoint.config")
    assert_same(reference_checkpoint, current_checkpoint, "checkpoint")

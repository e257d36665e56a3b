"""The pinned runtime set imports together, at the pinned versions (pip can leave a conflicting set behind)."""

import importlib
import importlib.metadata
import os
import re

import pytest

REQUIREMENTS = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "requirements.txt")
# distribution name -> module to import, for the direct dependencies
MODULES = {"torch": "torch", "gymnasium": "gymnasium", "numpy": "numpy", "tensorboard": "tensorboard",
           "tyro": "tyro", "tqdm": "tqdm", "ale-py": "ale_py", "procgen-mirror": "procgen", "minigrid": "minigrid",
           "pybullet": "pybullet", "pybullet-envs-gymnasium": "pybullet_envs_gymnasium", "ray": "ray",
           "matplotlib": "matplotlib", "cffi": "cffi", "stable-baselines3": "stable_baselines3", "pandas": "pandas",
           "pyarrow": "pyarrow", "tensorboardx": "tensorboardX", "pydantic": "pydantic", "scikit-learn": "sklearn",
           "scipy": "scipy", "dm-control": "dm_control.suite", "mujoco": "mujoco", "wandb": "wandb", "av": "av"}
# Ray Tune and PB2 (hpo_baselines.py) import only with their extras present, at these pins.
EXTRA_MODULES = ["ray.tune", "ray.tune.schedulers.pb2"]


def pins() -> dict[str, str]:
    found = {}
    for line in open(REQUIREMENTS):
        match = re.match(r"^([A-Za-z0-9_.\-]+)==([^\s#]+)", line)
        if match:
            found[match.group(1).lower().replace("_", "-")] = match.group(2)
    return found


def test_every_direct_dependency_is_pinned():
    assert set(MODULES) <= set(pins())


@pytest.mark.parametrize("distribution", sorted(pins()))
def test_installed_version_matches_pin(distribution):
    installed = importlib.metadata.version(distribution)
    assert installed.split("+")[0] == pins()[distribution]  # torch's local label (+cpu, +cu12x) may differ


@pytest.mark.parametrize("distribution, module", sorted(MODULES.items()))
def test_direct_dependency_imports(distribution, module):
    importlib.import_module(module)


@pytest.mark.parametrize("module", EXTRA_MODULES)
def test_ray_tune_and_pb2_import(module):
    importlib.import_module(module)

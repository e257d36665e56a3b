"""Fixtures that more than one test file reads, and the thread count of every torch the suite starts."""

import os

# One thread per torch process (the workers', the scripts' they start, Ray's): the suite runs several at once on
# each core, and at torch's default of a thread per core they spin in OpenMP's waits, 3-5x slower
# (docs/development.md). Set before anything imports torch.
os.environ.setdefault("OMP_NUM_THREADS", "1")

import pytest
from filelock import FileLock

from hpo_study import RAY_TOKEN_FILE, study


@pytest.fixture(scope="session")
def pbt_study(tmp_path_factory):
    """One real PBT study (population 3, an exploit possible every two iterations, every checkpoint kept), run
    once for the tests of hpo_baselines.py and of the report: (study directory, the tool's stdout).
    Under pytest-xdist the workers share it: the first to ask runs it, the others wait and read its output."""
    under_xdist = "PYTEST_XDIST_WORKER" in os.environ
    shared = tmp_path_factory.getbasetemp().parent if under_xdist else tmp_path_factory.mktemp("pbt")
    study_dir, output = shared / "pbt_study", shared / "pbt_study.output"
    with FileLock(str(shared / "pbt_study.lock")):
        if not output.exists():
            token_before = os.path.exists(RAY_TOKEN_FILE)
            result = study(study_dir, "--method", "pbt", "--population", "3", "--keep-checkpoints", "0")
            assert result.returncode == 0, result.stdout + result.stderr
            # The local Ray instance had a token of its own: Ray leaves none in the home directory, where every
            # later `ray start` on the machine would demand it.
            assert os.path.exists(RAY_TOKEN_FILE) == token_before
            output.write_text(result.stdout)
    return study_dir, output.read_text()

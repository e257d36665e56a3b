"""Fixtures that more than one test file reads."""

import os

import pytest

from hpo_study import RAY_TOKEN_FILE, study


@pytest.fixture(scope="session")
def pbt_study(tmp_path_factory):
    """One real PBT study (population 3, an exploit possible every two iterations, every checkpoint kept), run
    once for the tests of hpo_baselines.py and of the report: (study directory, the tool's CompletedProcess)."""
    study_dir = tmp_path_factory.mktemp("pbt") / "s"
    token_before = os.path.exists(RAY_TOKEN_FILE)
    result = study(study_dir, "--method", "pbt", "--population", "3", "--keep-checkpoints", "0")
    assert result.returncode == 0, result.stdout + result.stderr
    # The local Ray instance had a token of its own: Ray leaves none in the home directory, where every later
    # `ray start` on the machine would demand it.
    assert os.path.exists(RAY_TOKEN_FILE) == token_before
    return study_dir, result

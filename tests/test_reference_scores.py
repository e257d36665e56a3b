"""The reference scores stand three times: in the report (ultho_reporting/references.py), which normalizes every
run it reports; in the ALE and Procgen scripts, which write normalized scores into summary.json and TensorBoard
(each script stays one self-contained file); and in docs/paper.md's tables. All must give the same numbers for
every game."""

import os
import re

import pytest

import ppo_ultho_atari
import ppo_ultho_procgen
from helpers import REPO
from ultho_reporting.references import ALE_HUMAN, PROCGEN_EASY, PYBULLET_REFERENCE, normalized


def test_the_scripts_and_the_report_hold_the_same_reference_scores():
    assert ppo_ultho_atari.HUMAN_NORMALIZATION == ALE_HUMAN
    assert ppo_ultho_procgen.EASY_MODE_RANGE == PROCGEN_EASY
    assert set(PROCGEN_EASY) == set(ppo_ultho_procgen.GAMES)


@pytest.mark.parametrize("game", sorted(ALE_HUMAN))
def test_ale_scores_normalize_alike_by_every_name_of_the_game(game):
    for env_id in (game, f"ALE/{game}-v5", f"{game}NoFrameskip-v4"):
        for raw in (-20.0, 0.0, 1234.5):
            assert ppo_ultho_atari.human_normalized(env_id, raw) == normalized("atari", env_id, raw), env_id


@pytest.mark.parametrize("game", sorted(PROCGEN_EASY))
def test_procgen_scores_normalize_alike(game):
    for raw in (-2.0, 0.0, 7.25):
        assert ppo_ultho_procgen.normalized_score(game, raw) == normalized("procgen", game, raw)


def test_docs_paper_tables_hold_the_reports_reference_scores():
    with open(os.path.join(REPO, "docs", "paper.md")) as f:
        section = f.read().split("## Score normalization constants", 1)[1].split("\n## ", 1)[0]
    rows = {}  # first cell of a row (a game or task) -> its two numbers; the Procgen table has two games a row
    for line in section.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        for k in range(0, len(cells) - 2, 3):
            if re.fullmatch(r"-?[\d,.]+", cells[k + 1]) and re.fullmatch(r"-?[\d,.]+", cells[k + 2]):
                rows[cells[k].removesuffix("-v0")] = tuple(float(c.replace(",", "")) for c in cells[k + 1:k + 3])
    assert rows == {**PROCGEN_EASY, **ALE_HUMAN, **PYBULLET_REFERENCE}

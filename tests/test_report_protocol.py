"""The paper's best-(c, W) protocol in the report, on made-up scores worked out by hand."""

import numpy as np
import pytest

from ultho_reporting.protocol import expected_best_of_groups, family_of, best_points, protocol_section
from ultho_reporting.runs import Run, Study


def made(kind, env, score, seed, c=None, window=None, space=None):
    return Run(f"{kind}{c}{window}{env}{seed}", "minigrid", env, kind, c, window, seed, 500_000, score,
               search_space=space)


def study_of(runs):
    study = Study()
    study.runs = runs
    study.normalize()
    study.label_methods()
    return study


SPACE = {"learning_rate": [1e-3, 2e-3]}


def test_the_expected_best_of_two_groups_of_two_by_hand():
    # Group means of two draws from {2, 4}: 2 (1/4), 3 (1/2), 4 (1/4). The best of two groups: 4 with probability
    # 1 - (3/4)^2 = 7/16, 2 with (1/4)^2 = 1/16, else 3: 4*7/16 + 3*8/16 + 2*1/16 = 54/16 = 3.375.
    assert expected_best_of_groups(np.array([2.0, 4.0]), 2, 2, 0, 200_000) == pytest.approx(
        3.375, abs=0.01)


def test_with_enough_runs_the_groups_are_distinct_runs_by_hand():
    # Two groups of two out of {0, 1, 2, 3}, no run twice: the splits {0,1|2,3}, {0,2|1,3}, {0,3|1,2} are equally
    # likely and their better group means are 2.5, 2 and 1.5: 2 on average (drawn with replacement, 1.95).
    assert expected_best_of_groups(np.array([0.0, 1.0, 2.0, 3.0]), 2, 2, 0, 100_000) == pytest.approx(2.0, abs=0.01)
    # Four runs, one group of four: always all of them.
    assert expected_best_of_groups(np.array([0.0, 1.0, 2.0, 3.0]), 1, 4, 0, 100) == pytest.approx(1.5)


def test_family_drops_c_and_w_only():
    assert family_of("ULTHO (c=5, W=10)") == "ULTHO"
    assert family_of("ULTHO ts/improvement/running (W=10)") == "ULTHO ts/improvement/running"
    assert family_of("ULTHO authors-return (c=5, W=10) on update_epochs=10/5") == \
        "ULTHO authors-return on update_epochs=10/5"


def test_the_best_point_per_environment_beside_the_same_selection_on_ppo():
    runs = [made("ppo", "A", 0.2, 1), made("ppo", "A", 0.4, 2),
            made("ultho", "A", 0.1, 1, 5.0, 10, SPACE), made("ultho", "A", 0.3, 2, 5.0, 10, SPACE),
            made("ultho", "A", 0.4, 1, 1.0, 50, SPACE), made("ultho", "A", 0.6, 2, 1.0, 50, SPACE),
            made("ultho", "B", 0.9, 1, 5.0, 10, SPACE)]  # one point on B: no grid there
    study = study_of(runs)
    [found] = best_points(study.runs, "minigrid", seed=0, reps=200_000)
    assert (found.env_id, found.family, found.points, found.seeds) == ("A", "ULTHO", 2, 2)
    assert found.best_point == (1.0, 50) and found.best == pytest.approx(0.5)
    assert found.mean_of_points == pytest.approx((0.2 + 0.5) / 2)
    assert found.ppo == pytest.approx(0.3) and found.ppo_runs == 2
    assert found.ppo_best == pytest.approx(0.3375, abs=0.001)  # the hand-worked 3.375 above, / 10 (0.337 drawn)
    lines = protocol_section(study.runs, "minigrid", 0, 200_000)
    assert lines[0].startswith("### The paper's protocol")
    row = next(line for line in lines if line.startswith("| A |"))
    assert row.startswith("| A | ULTHO | 2 x 2 | c=1, W=50 | 0.500 | 0.350 | 0.300 (2) | 0.337 (bootstrap) |")


def test_no_grid_no_section():
    study = study_of([made("ppo", "A", 0.2, 1), made("ultho", "A", 0.1, 1, 5.0, 10, SPACE)])
    assert protocol_section(study.runs, "minigrid", 0, 1000) == []


def test_points_are_compared_on_the_seeds_they_all_have():
    # A grid still running: c=5, W=10 on seeds 1-3 (mean 0.433), c=1, W=50 on seed 1 only (0.4). On all their seeds
    # the first would win by its seeds 2 and 3; on the shared seed 1 it scores 0.1 against 0.4.
    runs = [made("ppo", "A", 0.2, 1), made("ppo", "A", 0.4, 2),
            made("ultho", "A", 0.1, 1, 5.0, 10, SPACE), made("ultho", "A", 0.3, 2, 5.0, 10, SPACE),
            made("ultho", "A", 0.9, 3, 5.0, 10, SPACE), made("ultho", "A", 0.4, 1, 1.0, 50, SPACE),
            made("ultho", "B", 0.5, 1, 5.0, 10, SPACE), made("ultho", "B", 0.6, 2, 1.0, 50, SPACE)]  # B: no shared seed
    [found] = best_points(study_of(runs).runs, "minigrid", seed=0, reps=1000)
    assert (found.env_id, found.points, found.seeds) == ("A", 2, 1)
    assert found.best_point == (1.0, 50) and found.best == pytest.approx(0.4)
    assert found.mean_of_points == pytest.approx((0.1 + 0.4) / 2)

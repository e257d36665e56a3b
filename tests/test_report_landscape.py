"""The landscape of fixed settings in the report: its numbers on made-up scores worked out by hand, and the
section and figure on a real tiny grid."""

import os

import numpy as np
import pytest

from helpers import run
from ultho_reporting.landscape import (best_chosen_on_other_seeds, failing, gains_with_intervals, landscape_section,
                                      landscapes, percentile)
from ultho_reporting.runs import Run, Study

SCORES = {1e-3: (0.5, 0.7), 2.5e-3: (0.8, 0.6), 5e-3: (0.1, 0.3)}  # learning rate: final scores of seeds 1 and 2


def made_study(tmp_path):
    runs = [Run(f"ppo{lr}{seed}", "minigrid", "E", "ppo", None, None, seed, 500_000, score,
                settings={"learning_rate": lr, "seed": seed, "minibatch_size": 256}, grid=True)
            for lr, scores in SCORES.items() for seed, score in zip((1, 2), scores)]
    # Fixed PPO at the defaults outside the grid (the report's baseline runs): a method placed among the settings.
    runs += [Run("ppo-defaults", "minigrid", "E", "ppo", None, None, 3, 500_000, 0.62,
                 settings={"learning_rate": 1e-3, "seed": 3, "minibatch_size": 256})]
    held = np.array([[1, 2.5e-3], [2, 2.5e-3], [3, 1e-3]])  # hparams/learning_rate: (step, value)
    runs += [Run(f"ultho{seed}", "minigrid", "E", "ultho", 5.0, 10, seed, 500_000, score,
                 search_space={"learning_rate": list(SCORES)}, series={"hparams/learning_rate": held})
             for seed, score in ((1, 0.65), (2, 0.75))]
    study = Study()
    study.runs = runs
    study.normalize()
    study.label_methods()
    return study


def test_the_settings_ranked_and_each_method_placed_among_them_by_hand(tmp_path):
    study = made_study(tmp_path)
    grid = landscapes(study.runs)["E"]
    # Means 0.6 (1e-3, the script's default), 0.7 (2.5e-3), 0.2 (5e-3): best first.
    assert [s.values["learning_rate"] for s in grid] == [2.5e-3, 1e-3, 5e-3]
    assert [s.final for s in grid] == pytest.approx([0.7, 0.6, 0.2])
    # ULTHO's mean 0.7: above 0.6 and 0.2, level with 0.7 (half): 2.5 of 3.
    assert percentile(0.7, grid) == pytest.approx(100 * 2.5 / 3)
    # Seed 1 held out: seed 2 picks 1e-3 (0.7 > 0.6), which scores 0.5 on seed 1; seed 2 held out: seed 1 picks
    # 2.5e-3 (0.8), which scores 0.6 on seed 2. A grid search could expect (0.5 + 0.6) / 2.
    assert best_chosen_on_other_seeds(grid) == pytest.approx(0.55)
    # Means 0.7 (best), 0.6 (defaults, also the median): +0.1, 0, +0.1. Resampled, 1e-3's mean is 0.5, 0.6 or 0.7,
    # 2.5e-3's 0.6, 0.7 or 0.8, and 5e-3's (at most 0.3) is always the lowest, so the median is the smaller of the
    # other two: best - defaults = max(0, m(2.5e-3) - m(1e-3)) lies in [0, 0.3], defaults - median =
    # max(0, m(1e-3) - m(2.5e-3)) in [0, 0.1], best - median = |m(1e-3) - m(2.5e-3)| in [0, 0.3].
    gains = gains_with_intervals(grid, grid[1], seed=0, reps=2000)
    assert [name for name in gains] == ["best − defaults", "defaults − median", "best − median"]
    for (name, (point, low, high)), (expected, floor, ceiling) in zip(gains.items(), [(0.1, 0, 0.3), (0, 0, 0.1),
                                                                                       (0.1, 0, 0.3)]):
        assert point == pytest.approx(expected) and floor - 1e-9 <= low <= point <= high <= ceiling + 1e-9, name
    # 5e-3's seed 1 (0.1) is below half the best mean (0.35): a failed run.
    assert [s.values["learning_rate"] for s in failing(grid)] == [5e-3]
    lines = landscape_section(study.runs, "minigrid", str(tmp_path), lambda v: f"{v:.3f}")
    text = "\n".join(lines)
    assert "3 settings; best 0.700 (0.0025), median 0.600, worst 0.200 (0.005)" in text
    assert "the defaults (0.001) rank 2 of 3 at 0.600" in text
    assert "the best setting chosen on the other seeds scores 0.550" in text
    assert "best − defaults +0.1 [" in text and "Settings with a failed seed (below half the best mean): 0.005 " \
        "(0.100, 0.300)" in text
    row = next(line for line in lines if line.startswith("| ULTHO (c=5, W=10) |"))
    # 0.7: percentile 83; +0.1 over the median and the defaults, level with the best; no round robin; one run a
    # seed; both runs held 2.5e-3 longest, the best setting. Resampled, ULTHO's mean is 0.65, 0.7 or 0.75 and the
    # defaults' 0.5, 0.6 or 0.7 (each extreme with probability 1/4), so the difference's extremes, -0.05 and
    # +0.25, each have probability 1/16 > 2.5%: they are the interval's ends; against the best (0.6, 0.7 or 0.8),
    # -0.15 and +0.15.
    assert row == "| ULTHO (c=5, W=10) | 0.700 | 83 | +0.1 | +0.1 [-0.05, +0.25] | +0 [-0.15, +0.15] | – | 1 | 1, 1 |"
    # 0.62: above 0.6 and 0.2 (67), 0.02 over the median and the defaults' grid runs, 0.08 under the best; one run
    # against two: 0.62 minus 0.5, 0.6 or 0.7, and minus 0.6, 0.7 or 0.8.
    assert "| PPO | 0.620 | 67 | +0.02 | +0.02 [-0.08, +0.12] | -0.08 [-0.18, +0.02] | – | 1 | – |" in lines
    assert os.path.exists(tmp_path / "landscape_minigrid_E.png")


def test_one_setting_is_no_landscape(tmp_path):
    study = made_study(tmp_path)
    study.runs = [r for r in study.runs if not r.grid or r.settings["learning_rate"] == 1e-3]
    assert landscapes(study.runs) == {}
    assert landscape_section(study.runs, "minigrid", str(tmp_path), str) == []


def test_without_a_grid_the_fixed_settings_runs_are_the_landscape(tmp_path):
    # Fixed PPO at 10 epochs (the script's default) and at 5, no grid: the oracle of a two-value space.
    finals = {10: (2000, 2200), 5: (1800, 1900)}
    runs = [Run(f"ppo{epochs}-{seed}", "pybullet", "E", "ppo", None, None, seed, 2_000_000, score,
                settings={"update_epochs": epochs, "seed": seed})
            for epochs, scores in finals.items() for seed, score in zip((1, 2), scores)]
    runs += [Run(f"ultho{seed}", "pybullet", "E", "ultho", 5.0, 10, seed, 2_000_000, score,
                 search_space={"update_epochs": [10, 5]}) for seed, score in ((1, 1950), (2, 2050))]
    # The round robin over the same two values, and ULTHO over another space, which has no round robin to face.
    runs += [Run(f"rr{seed}", "pybullet", "E", "ultho", None, None, seed, 2_000_000, score,
                 search_space={"update_epochs": [10, 5]}, variant="round-robin:level:none")
             for seed, score in ((1, 1900), (2, 1900))]
    runs += [Run(f"other{seed}", "pybullet", "E", "ultho", 5.0, 10, seed, 2_000_000, 1800,
                 search_space={"learning_rate": [2e-4, 5e-4]}) for seed in (1, 2)]
    study = Study()
    study.runs = runs
    study.normalize()
    study.label_methods()
    grid = landscapes(study.runs)["E"]
    assert [s.values for s in grid] == [{"update_epochs": 10}, {"update_epochs": 5}]
    lines = landscape_section(study.runs, "pybullet", str(tmp_path), lambda v: f"{v:.0f}")
    text = "\n".join(lines)
    assert "2 settings; best 2100 (10), median 1975, worst 1850 (5); the defaults (10) rank 1 of 2" in text
    # ULTHO's mean 2000: above 1850, below 2100 (percentile 50), +25 over the median, 100 under the defaults, which
    # are the best; the fixed runs are the settings, not methods placed among them. Resampled: ULTHO 1950, 2000 or
    # 2050 minus the defaults' 2000, 2100 or 2200 (extremes at 1/16 each): [-250, +50]; minus the round robin's
    # 1900 every time: +100 [+50, +150].
    assert "| ULTHO (c=5, W=10) | 2000 | 50 | +25 | -100 [-250, +50] | -100 [-250, +50] | +100 [+50, +150] | 1 | – |" \
        in lines
    # The round robin faces no round robin; ULTHO over the learning rate faces none on its own values.
    assert "| Round robin | 1900 | 50 | -75 | -200 [-300, -100] | -200 [-300, -100] | – | 1 | – |" in lines
    assert "| ULTHO (c=5, W=10) on learning_rate=0.0002/0.0005 | 1800 | 0 | -175 | -300 [-400, -200] | " \
        "-300 [-400, -200] | – | 1 | – |" in lines
    assert not any(line.startswith("| PPO") for line in lines)


def test_a_real_tiny_grid_draws_its_landscape(tmp_path):
    out = tmp_path / "grid"
    swept = run("sweep.py", "--scripts", "ppo_ultho_minigrid.py", "--env-ids", "MiniGrid-Empty-5x5-v0", "--methods",
                "grid", "ultho", "--grid-clusters", "minibatch_size=32,64", "vf_coef=0.5,1.0", "--total-timesteps",
                "512", "--workers", "2", "--out", str(out), "--", "--num-envs", "4", "--num-steps", "64",
                "--eval-episodes", "0", "--ultho-clusters", "minibatch_size=32,64", "vf_coef=0.5,1.0")
    assert swept.returncode == 0, swept.stderr
    report = run("ultho_report.py", str(out), "--out", str(tmp_path / "report"), "--reps", "200", "--no-per-run")
    assert report.returncode == 0, report.stderr
    text = (tmp_path / "report" / "report.md").read_text()
    assert "### The landscape of fixed settings" in text and "4 settings; best" in text
    assert "landscape_minigrid_MiniGrid_Empty_5x5_v0.png" in text
    assert (tmp_path / "report" / "landscape_minigrid_MiniGrid_Empty_5x5_v0.png").exists()
    assert "| ULTHO (c=5, W=10) |" in text
    # The grid's runs are in that section alone: the report's other tables and curves have ULTHO only.
    assert "| PPO" not in text.split("### The landscape of fixed settings")[0]

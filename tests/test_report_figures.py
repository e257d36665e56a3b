"""The report's figures read in seconds: what each draws, read back from the matplotlib figure itself, on made-up
runs (no training), and the committed results folders' figures all linked."""

import dataclasses
import os
import re

import numpy as np
import pytest

import ultho_reporting.figures as figures
from ultho_reporting.figures import (coinciding, compact, decision_figures, method_groups, method_styles,
                                     robustness_figure)
from ultho_reporting.runs import Run, Study

from helpers import REPO

SPACE = {"learning_rate": [1e-3, 2.5e-3, 5e-3], "minibatch_size": [128, 256, 512], "vf_coef": [0.25, 0.5, 1.0]}
STEPS = np.arange(1, 41) * 1000.0


def ultho_run(env: str, seed: int, c: float = 5.0, window: int = 10, score: float = 0.5,
              benchmark: str = "minigrid", variant: str = "ucb:level:none", chosen: int = 2) -> Run:
    """A ULTHO run whose bandit chose only cluster ``chosen`` (its first value) and held the others at the script's
    settings (the fixed-settings runs': 1e-3, 256, 0.5)."""
    count = len(STEPS)
    series = {"ultho/selected_cluster": np.column_stack([STEPS, np.full(count, chosen)]),
              "ultho/selected_value_index": np.column_stack([STEPS, np.zeros(count)])}
    held = {"learning_rate": 1e-3, "minibatch_size": 256, "vf_coef": 0.5}
    for k, cluster in enumerate(SPACE):
        value = SPACE[cluster][0] if k == chosen else held[cluster]
        series[f"hparams/{cluster}"] = np.column_stack([STEPS, np.full(count, value)])
        utility = np.linspace(0, 1, count) if k == chosen else np.zeros(count)  # the others never credited
        series[f"ultho/utility/{cluster}"] = np.column_stack([STEPS, utility])
        series[f"ultho/ucb/{cluster}"] = np.column_stack([STEPS, utility + 0.5])
    return Run(f"{env}-{c}-{window}-{seed}", benchmark, env, "ultho", c, window, seed, 40_000, score,
               search_space=SPACE, series=series, variant=variant)


def fixed_run(env: str, seed: int, score: float = 0.5, benchmark: str = "minigrid") -> Run:
    return Run(f"{env}-ppo-{seed}", benchmark, env, "ppo", None, None, seed, 40_000, score,
               settings={"learning_rate": 1e-3, "minibatch_size": 256, "vf_coef": 0.5, "seed": seed})


def labelled(runs: list[Run]) -> list[Run]:
    study = Study()
    study.runs = runs
    study.normalize()
    study.label_methods()
    return study.runs


@pytest.fixture
def drawn(monkeypatch):
    """The figures the functions save, by file name, kept open for reading."""
    kept = {}

    def keep(figure, out, name):
        kept[name] = figure
        return name

    monkeypatch.setattr(figures, "save", keep)
    return kept


def test_values_read_as_short_ticks():
    assert [compact(v) for v in (3e-4, 0.0025, 0.01, 1e-4, 256, 0.5, 1.0)] == \
        ["3e-4", "2.5e-3", "0.01", "1e-4", "256", "0.5", "1"]


def test_the_decision_figure_has_a_row_per_environment_with_the_fixed_settings_marked(drawn):
    runs = labelled([ultho_run(env, seed) for env in ("A", "B") for seed in (1, 2)] + [fixed_run("A", 1)])
    ultho = [r for r in runs if r.kind == "ultho"]
    fixed = {"learning_rate": 1e-3, "minibatch_size": 256, "vf_coef": 0.5}
    names = decision_figures(ultho, "MiniGrid ULTHO", "unused", "minigrid_ULTHO", fixed, "PPO")
    assert [what for what, _ in names] == ["decision process", "confidence bounds"]
    figure = drawn["decision_minigrid_ULTHO.png"]
    rows = figure.subfigs
    assert [row._suptitle.get_text() for row in rows] == ["A (2 runs)", "B (2 runs)"]
    held = rows[0].axes[2]  # which value is in force
    hatched = [round(bar.get_height()) for bar in held.patches if bar.get_hatch()]
    # The bandit chose vf_coef=0.25 throughout; learning rate and minibatch size kept the fixed settings'.
    assert hatched == [100, 100, 0]
    bold = [t.get_text() for t in held.get_xticklabels() if t.get_fontweight() == "bold"]
    assert bold == ["1e-3", "256", "0.5"]
    bounds = drawn["bounds_minigrid_ULTHO.png"]
    titles = [axes.get_title() for axes in bounds.axes if axes.get_visible()]
    assert len(titles) == 2 and all(t.startswith(env) for t, env in zip(titles, "AB"))
    # learning_rate and minibatch_size were never chosen: their lines coincide and are named, once each.
    assert all("learning_rate, minibatch_size: U and U + bonus" in " ".join(t.split()) for t in titles)


def test_with_one_cluster_each_run_is_a_strip_of_the_values_it_chose(drawn):
    """The authors' PyBullet space: one run settles on 5 after two iterations, one rotates; a mean over them would
    show a 70/30 mixture neither ran."""
    space = {"update_epochs": [10, 5]}
    settled, rotating = [0, 1] + [1] * 38, [0, 1] * 20
    runs = []
    for seed, picks in ((2, rotating), (1, settled)):
        series = {"ultho/selected_cluster": np.column_stack([STEPS, np.zeros(40)]),
                  "ultho/selected_value_index": np.column_stack([STEPS, picks]),
                  "hparams/update_epochs": np.column_stack([STEPS, [space["update_epochs"][p] for p in picks]])}
        runs.append(Run(f"A-{seed}", "pybullet", "A", "ultho", 5.0, 10, seed, 40_000, 0.5, search_space=space,
                        series=series, variant="ucb:level:none", utility="authors-return"))
    decision_figures(runs, "PyBullet authors", "unused", "authors", {"update_epochs": 10}, "PPO")
    strips = drawn["decision_authors.png"].subfigs[0].axes[0]
    assert [t.get_text() for t in strips.get_yticklabels()] == ["seed 1", "seed 2"]
    colour = {tuple(h.get_facecolor()): h.get_label() for h in drawn["decision_authors.png"].legends[0].legend_handles}
    bars = {0: [], 1: []}  # row: [(start, width, label)] of the strips' bars
    for collection in strips.collections:
        corners = collection.get_paths()[0].vertices
        start, end, row = corners[:, 0].min(), corners[:, 0].max(), int(round(corners[:, 1].mean()))
        bars[row].append((start, end - start, colour[tuple(collection.get_facecolor()[0])]))
    assert [label for _, _, label in sorted(bars[0])] == ["update_epochs = 10 (strips)", "update_epochs = 5 (strips)"]
    assert sorted(bars[0])[1][:2] == (2000.0, 39000.0)  # from iteration 2's step to the run's end
    assert len(bars[1]) == 40  # the rotation: a new bar at every iteration


def test_a_long_rotation_is_drawn_as_even_bands_not_aliased_into_one_colour(drawn):
    """976 iterations (PyBullet's 2M steps) are more than the strip's pixels: drawn a bar an iteration, a round robin
    showed as the colour drawn last. Chunks of whole rotations show it as two even bands over the whole run; a run
    that switches once shows as two full-height stretches."""
    space = {"update_epochs": [10, 5]}
    steps = np.arange(1, 977) * 2048.0
    runs = []
    for seed, picks in ((1, [0, 1] * 488), (2, [0] * 500 + [1] * 476)):
        series = {"ultho/selected_cluster": np.column_stack([steps, np.zeros(976)]),
                  "ultho/selected_value_index": np.column_stack([steps, picks])}
        runs.append(Run(f"A-{seed}", "pybullet", "A", "ultho", 5.0, 10, seed, 2_000_000, 0.5, search_space=space,
                        series=series, variant="round-robin:level:none"))
    decision_figures(runs, "PyBullet round robin", "unused", "rr", {"update_epochs": 10}, "PPO")
    strips = drawn["decision_rr.png"].subfigs[0].axes[0]
    bars = {0: [], 1: []}  # row: [(start, end, bottom, height)]
    for collection in strips.collections:
        corners = collection.get_paths()[0].vertices
        bottom, top = corners[:, 1].min(), corners[:, 1].max()
        bars[int(round((bottom + top) / 2))].append((corners[:, 0].min(), corners[:, 0].max(),
                                                     round(bottom, 6), round(top - bottom, 6)))
    end = 977 * 2048.0
    assert sorted(bars[0]) == [(2048.0, end, -0.4, 0.4), (2048.0, end, 0.0, 0.4)]
    # The switch at iteration 501 falls inside the chunk of iterations 499-504: 2 of its 6 on 10, 4 on 5.
    assert [(round(b[0]), round(b[3], 4)) for b in sorted(bars[1])] == [(2048, 0.8), (499 * 2048, 0.2667),
                                                                        (499 * 2048, 0.5333), (505 * 2048, 0.8)]


def test_lines_that_coincide_are_grouped():
    zero, one = np.zeros(5), np.ones(5)
    assert coinciding([zero, one, zero + 1e-9, one * 2], 1e-6) == [[0, 2], [1], [3]]


def test_robustness_panels_share_one_y_range_and_a_single_point_is_not_a_figure(drawn):
    a, b, c_env = "MiniGrid-DoorKey-6x6-v0", "MiniGrid-Empty-16x16-v0", "MiniGrid-LavaGapS7-v0"
    runs = [ultho_run(env, seed, c, window, score)
            for env, base in ((a, 0.95), (b, 0.3)) for c, window in ((1.0, 10), (5.0, 10))
            for seed, score in ((1, base), (2, base + 0.01 * c))]
    runs += [ultho_run(c_env, seed, score=0.5) for seed in (1, 2)]  # one (c, W) point: no panel
    runs = labelled(runs + [fixed_run(env, 1) for env in (a, b, c_env)])
    name, empty, single = robustness_figure(runs, "minigrid", {}, 0, 200, "unused")
    assert name == "robustness_minigrid.png" and empty == [] and single == [(c_env, 5.0, 10)]
    panels = [axes for axes in drawn[name].axes if axes.get_visible()]
    assert [axes.get_title() for axes in panels] == [a, b]
    # One y range: a's points (95-96%) and b's (30-31%) both within it, so a's spread looks as small as it is.
    low, high = panels[0].get_ylim()
    assert {axes.get_ylim() for axes in panels} == {(low, high)} and low < 30 and high > 96
    only_one = labelled([ultho_run(c_env, seed) for seed in (1, 2)])
    assert robustness_figure(only_one, "minigrid", {}, 0, 200, "unused") == (None, [], [(c_env, 5.0, 10)])


def test_robustness_is_the_papers_bandit_against_plain_ppo(drawn):
    """Runs at the same (c, W) with another credit are another method, and fixed PPO at other settings is not the
    baseline's line."""
    env = "MiniGrid-Empty-16x16-v0"
    paper = [ultho_run(env, seed, c, window, score=0.9) for c, window in ((1.0, 50), (5.0, 10)) for seed in (1, 2)]
    authors = [dataclasses.replace(ultho_run(env, seed, 1.0, 10, score=0.1), utility="authors-return")
               for seed in (1, 2)]
    other_ppo = [dataclasses.replace(fixed_run(env, seed, score=0.1), path=f"ppo-512-{seed}",
                                     settings={"minibatch_size": 512}) for seed in (1, 2)]
    runs = labelled(paper + authors + [fixed_run(env, 1, score=0.6)] + other_ppo)
    name, empty, single = robustness_figure(runs, "minigrid", {}, 0, 200, "unused")
    [panel] = [axes for axes in drawn[name].axes if axes.get_visible()]
    # Two points, both at 90%: the authors' credit at (1, 10) is no third point; the baseline's line is PPO's 60%.
    assert sorted(round(line.get_ydata()[0]) for line in panel.lines if line.get_marker() == "o") == [90, 90]
    [baseline] = [line for line in panel.lines if line.get_linestyle() == "--"]
    assert baseline.get_ydata()[0] == pytest.approx(60)


def test_dmc_labels_name_the_algorithm_ultho_tunes():
    dmc = labelled([ultho_run("cheetah-run", 1, benchmark="dmc"), fixed_run("cheetah-run", 1, benchmark="dmc")])
    assert sorted(r.label for r in dmc) == ["SAC", "SAC + ULTHO (c=5, W=10)"]
    minigrid = labelled([ultho_run("A", 1), fixed_run("A", 1)])
    assert sorted(r.label for r in minigrid) == ["PPO", "ULTHO (c=5, W=10)"]


def test_many_methods_are_drawn_in_groups_each_with_its_own_style():
    runs = [fixed_run(env, 1) for env in "AB"]
    runs += [ultho_run(env, 1, c, w) for env in "AB" for c, w in ((1.0, 50), (5.0, 10))]
    runs += [ultho_run("A", 1, c, w) for c, w in ((1.0, 10), (5.0, 100))]  # the grid, on one environment
    runs += [ultho_run(env, 1, 1.0, 10, variant="ucb:level:running") for env in "AB"]
    relay = Run("relay", "minigrid", "A", "relay", 5.0, 10, 1, 120_000, 0.5)
    runs = labelled(runs + [relay])
    groups = method_groups(runs)
    # The paper's protocol: the relay and the point it relays; the rest of the grid (c=1, W=50 ran on A and B).
    assert [(g.key, g.labels) for g in groups] == [
        ("", ["PPO", "ULTHO (c=5, W=10)", "Relay-ULTHO (c=5, W=10)"]),
        ("grid", ["PPO", "ULTHO (c=1, W=10)", "ULTHO (c=1, W=50)", "ULTHO (c=5, W=10)", "ULTHO (c=5, W=100)"]),
        ("variants", ["PPO", "ULTHO ucb/level/running (c=1, W=10)"])]
    assert groups[1].envs == ("A", "B") and groups[1].by_c
    # Without a relay (and another variant, so that the methods still need groups): the points run on every
    # environment.
    unrelayed = method_groups(labelled([r for r in runs if r.kind != "relay"]
                                       + [ultho_run("A", 1, variant="ts:improvement:running")]))
    assert [(g.key, g.labels) for g in unrelayed][:2] == [
        ("", ["PPO", "ULTHO (c=1, W=50)", "ULTHO (c=5, W=10)"]),
        ("grid", ["PPO", "ULTHO (c=1, W=10)", "ULTHO (c=1, W=50)", "ULTHO (c=5, W=10)", "ULTHO (c=5, W=100)"])]
    assert unrelayed[1].envs == ("A",)
    styles = method_styles(runs)
    assert styles["PPO"].color == "black"
    assert len({(s.color, s.linestyle) for s in styles.values()}) == len(styles)
    # A relay is dashed in the colour of the ULTHO point it relays.
    assert (styles["Relay-ULTHO (c=5, W=10)"].color, styles["Relay-ULTHO (c=5, W=10)"].linestyle) == \
        (styles["ULTHO (c=5, W=10)"].color, "--")


def test_few_methods_are_one_figure():
    runs = labelled([fixed_run("A", 1), ultho_run("A", 1)])
    assert [(g.key, g.labels) for g in method_groups(runs)] == [("", ["PPO", "ULTHO (c=5, W=10)"])]


@pytest.mark.parametrize("folder", sorted(f for f in os.listdir(os.path.join(REPO, "results"))
                                          if os.path.isfile(os.path.join(REPO, "results", f, "report.md"))))
def test_every_committed_figure_is_linked_from_its_report(folder):
    """A figure the report no longer draws is deleted, not left beside it looking current."""
    where = os.path.join(REPO, "results", folder)
    with open(os.path.join(where, "report.md")) as f:
        linked = set(re.findall(r"\]\(([^)]+\.png)\)", f.read()))
    assert {name for name in os.listdir(where) if name.endswith(".png")} == linked

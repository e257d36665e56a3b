"""The landscape of fixed settings: where each method stands among every fixed setting a grid search would try.

A benchmark's grid is the runs a sweep.json lists as ``--methods grid`` (``sweep.py`` runs every combination of a
search space's values with ``--no-ultho``); every other run, the defaults' fixed-settings runs included, is a
method placed among its settings. A benchmark without a grid takes its fixed-settings runs as the settings when
they differ (fixed PPO at 10 and at 5 epochs: the oracle of a two-value space). For each environment with two or more
settings, the section ranks them by final score and by the area under the learning curve, draws them sorted with
the other methods' scores across, and places each other method among them: its percentile, its score against
the grid's median (what a setting picked at random gets), the script's defaults, the best setting and a round
robin over the same values (with intervals), and its cost in runs. The best setting chosen on the seeds it is
scored on is optimistic, so the section also gives the best setting chosen on the other seeds (leave one seed
out), which is what a grid search could expect.
"""

from dataclasses import dataclass

import matplotlib.pyplot as plt
import numpy as np

from ultho_reporting.figures import save, slug
from ultho_reporting.runs import Run, disagreeing_settings, script_defaults
from ultho_reporting.scores import normalized_area


@dataclass
class Setting:
    """One fixed setting of the grid on one environment, and its runs' scores."""

    values: dict  # {setting name: value}, the names the grid varies
    runs: list[Run]

    @property
    def finals(self) -> dict[int, float]:
        """{seed: final score}"""
        return {r.seed: r.raw_score for r in self.runs if r.raw_score is not None}

    @property
    def final(self) -> float:
        return float(np.mean(list(self.finals.values())))

    @property
    def area(self) -> float | None:
        areas = [a for a in map(normalized_area, self.runs) if a is not None]
        return float(np.mean(areas)) if areas else None

    def text(self) -> str:
        return " / ".join(f"{value:g}" if isinstance(value, (int, float)) and not isinstance(value, bool)
                          else str(value) for value in self.values.values())


def setting_runs(runs: list[Run]) -> list[Run]:
    """The runs that make a benchmark's landscape: its grid's; without a grid, its fixed-settings runs when they
    differ in a setting (as fixed PPO at two numbers of epochs: the oracle of a two-value space)."""
    return [r for r in runs if r.grid] or [r for r in runs if r.kind == "ppo"]


def grid_keys(runs: list[Run]) -> list[str]:
    """The settings on which a benchmark's landscape runs differ, in the order of their runs' settings."""
    return disagreeing_settings(setting_runs(runs), script_defaults(runs[0].benchmark) if runs else None)


def landscapes(runs: list[Run]) -> dict[str, list[Setting]]:
    """{environment: its fixed settings with scored runs}, for the environments with two settings or more."""
    keys = grid_keys(runs)
    found: dict[str, list[Setting]] = {}
    if not keys:
        return found
    fixed = setting_runs(runs)
    for env in sorted({r.env_id for r in fixed}):
        settings: dict[tuple, Setting] = {}
        for run in (r for r in fixed if r.env_id == env and r.raw_score is not None):
            values = {key: run.settings.get(key) for key in keys}
            settings.setdefault(tuple(values.values()), Setting(values, [])).runs.append(run)
        if len(settings) >= 2:
            found[env] = sorted(settings.values(), key=lambda s: -s.final)
    return found


def percentile(score: float, grid: list[Setting]) -> float:
    """The share of the settings (in %) whose mean final score is below ``score``, ties counted half."""
    finals = np.array([s.final for s in grid])
    return float(100 * (np.sum(finals < score) + 0.5 * np.sum(finals == score)) / len(finals))


def best_chosen_on_other_seeds(grid: list[Setting]) -> float | None:
    """A grid search's expected score: for each seed that every setting has, the setting with the best mean over
    the other seeds, scored on that seed; the mean over those seeds (None with fewer than two shared seeds)."""
    shared = sorted(set.intersection(*(set(s.finals) for s in grid)))
    if len(shared) < 2:
        return None
    picked = []
    for held_out in shared:
        others = [seed for seed in shared if seed != held_out]
        choice = max(grid, key=lambda s: np.mean([s.finals[seed] for seed in others]))
        picked.append(choice.finals[held_out])
    return float(np.mean(picked))


def defaults_of(grid: list[Setting], benchmark: str) -> Setting | None:
    """The setting at the script's own defaults, when the grid has it."""
    defaults = script_defaults(benchmark)
    for setting in grid:
        if all(defaults.get(key) == value for key, value in setting.values.items()):
            return setting
    return None


def held_longest(run: Run, keys: list[str]) -> tuple | None:
    """The value each of ``keys`` held for the most logged iterations of an ULTHO run (``hparams/*``)."""
    if not all(f"hparams/{key}" in run.series for key in keys):
        return None
    held = []
    for key in keys:
        values, counts = np.unique(run.series[f"hparams/{key}"][:, 1], return_counts=True)
        held.append(float(values[counts.argmax()]))
    return tuple(held)


def rank_of(values: tuple, grid: list[Setting]) -> int | None:
    """The 1-based rank by mean final score of the setting with these values (None when the grid lacks it)."""
    for rank, setting in enumerate(grid, start=1):
        if np.allclose([float(v) for v in setting.values.values()], values):
            return rank
    return None


def landscape_figure(env: str, grid: list[Setting], methods: dict[str, tuple[list[float], list[float]]],
                     defaults: Setting | None, benchmark: str, out: str) -> str:
    """One row per fixed setting (grey dot: its mean over seeds, bar: their range; the defaults in red) and per
    other method of the report (blue diamond and bar, named in bold), all sorted by their mean, so a method's row
    shows where it falls among the settings; a panel by final score and one by area under the curve. ``methods``:
    {label: (its runs' final scores, their areas)}. The axis starts just below the lowest mean: a failed seed's
    bar can run off its left edge."""
    panels = [("final score", lambda s: list(s.finals.values()), 0)]
    if all(s.area is not None for s in grid):
        panels.append(("area under the normalized curve",
                       lambda s: [a for a in map(normalized_area, s.runs) if a is not None], 1))
    rows_count = len(grid) + len(methods)
    figure, axes = plt.subplots(1, len(panels), figsize=(6.6 * len(panels), max(3.4, 1.5 + 0.23 * rows_count)),
                                squeeze=False, layout="constrained")
    for panel, (title, spread, index) in zip(axes[0], panels):
        rows = [(s.text() + (" (defaults)" if s is defaults else ""), spread(s),
                 "tab:red" if s is defaults else "0.45", False) for s in grid]
        rows += [(label, values[index], "tab:blue", True) for label, values in methods.items() if values[index]]
        rows.sort(key=lambda row: np.mean(row[1]))
        ys = np.arange(len(rows))
        for y, (_, values, color, is_method) in zip(ys, rows):
            panel.plot([min(values), max(values)], [y, y], color=color, alpha=0.4, linewidth=2.5)
            panel.plot(np.mean(values), y, "D" if is_method else "o", color=color, markersize=5)
        panel.set_yticks(ys, [row[0] for row in rows], fontsize=8)
        for tick, (_, _, color, is_method) in zip(panel.get_yticklabels(), rows):
            tick.set_color("0.15" if color == "0.45" else color)
            tick.set_fontweight("bold" if is_method else "normal")
        means = [float(np.mean(row[1])) for row in rows]
        low, high = min(means), max(max(row[1]) for row in rows)
        pad = 0.04 * (high - low) or 0.01
        panel.set_xlim(low - pad, high + pad)
        panel.set_ylim(-0.6, len(rows) - 0.4)
        panel.set_xlabel(title)
        panel.grid(axis="x", alpha=0.3)
    figure.suptitle(f"{env}: {len(grid)} fixed settings ({' / '.join(grid[0].values)}, grey; the defaults red) and "
                    "the report's methods (blue), best at the top\ndot: mean over seeds, bar: their range",
                    fontsize=10)
    return save(figure, out, f"landscape_{benchmark}_{slug(env)}.png")


def gains_with_intervals(grid: list[Setting], defaults: Setting | None, seed: int,
                         reps: int) -> dict[str, tuple[float, float, float]]:
    """What tuning these settings gains, with 95% percentile intervals from resampling each setting's seeds (with
    replacement, settings independently): best setting − defaults, defaults − median setting, best − median. The
    best is picked within each resample, so its interval carries the optimism of picking it on its own seeds."""
    common = min(len(s.finals) for s in grid)
    finals = np.array([list(s.finals.values())[:common] for s in grid])  # (settings, seeds)
    rng = np.random.default_rng(seed)
    draws = rng.integers(0, common, size=(reps, *finals.shape))
    means = np.take_along_axis(np.broadcast_to(finals, draws.shape), draws, axis=2).mean(axis=2)  # (reps, settings)
    best, median = means.max(axis=1), np.median(means, axis=1)
    point_means = finals.mean(axis=1)
    point_best, point_median = point_means.max(), float(np.median(point_means))
    found = {"best − median": (point_best - point_median, best - median)}
    if defaults is not None:
        k = grid.index(defaults)
        found = {"best − defaults": (point_best - point_means[k], best - means[:, k]),
                 "defaults − median": (point_means[k] - point_median, means[:, k] - median), **found}
    return {name: (float(point), *map(float, np.percentile(sampled, [2.5, 97.5])))
            for name, (point, sampled) in found.items()}


def difference_with_interval(scores: list[float], other: list[float], rng: np.random.Generator,
                             reps: int) -> tuple[float, float, float]:
    """mean(scores) − mean(other), with its 95% percentile interval from resampling each side's runs (with
    replacement, the two sides independently)."""
    a, b = np.asarray(scores, dtype=float), np.asarray(other, dtype=float)
    sampled = (a[rng.integers(0, len(a), size=(reps, len(a)))].mean(axis=1)
               - b[rng.integers(0, len(b), size=(reps, len(b)))].mean(axis=1))
    return float(a.mean() - b.mean()), *map(float, np.percentile(sampled, [2.5, 97.5]))


def signed(value: float) -> str:
    """A difference of scores with its sign: three significant digits, whole numbers from 100 on (1,040, not
    1.04e+03)."""
    return f"{value:+,.0f}" if abs(value) >= 100 else f"{value:+.3g}"


def difference_cell(members: list[Run], reference: list[float], rng: np.random.Generator, reps: int) -> str:
    """The method's runs' mean final score minus the reference's, with its interval ("–" without a reference)."""
    if not reference:
        return "–"
    point, low, high = difference_with_interval([r.raw_score for r in members], reference, rng, reps)
    return f"{signed(point)} [{signed(low)}, {signed(high)}]"


def is_round_robin(run: Run) -> bool:
    return run.kind == "ultho" and run.variant.startswith("round-robin:")


def round_robin_of(members: list[Run], others: list[Run]) -> list[Run]:
    """The round-robin runs on the search space of ULTHO runs ``members`` (none for a round robin itself): the
    control that takes the same values in turn, without a bandit."""
    if not members or members[0].kind != "ultho" or is_round_robin(members[0]):
        return []
    return [r for r in others if is_round_robin(r) and r.search_space == members[0].search_space]


def failing(grid: list[Setting]) -> list[Setting]:
    """The settings with a seed below half the best setting's mean final score: a run that failed."""
    return [s for s in grid if min(s.finals.values()) < 0.5 * grid[0].final]


def landscape_section(runs: list[Run], benchmark: str, out: str, number, seed: int = 0,
                      reps: int = 10_000) -> list[str]:
    """The section's lines (none without a grid of fixed settings); ``number`` formats a raw score; ``seed`` and
    ``reps`` drive the intervals' resampling."""
    found = landscapes(runs)
    if not found:
        return []
    keys = grid_keys(runs)
    budget = int(np.median([r.budget for grid in found.values() for s in grid for r in s.runs]))
    lines = ["### The landscape of fixed settings", "",
             f"Every fixed setting of {', '.join(keys)} that was run, per environment, ranked by mean final score "
             "over its seeds; the methods of this report placed among them: their percentile among the settings "
             "(100: above all), their mean final score minus the grid's median setting's (what a setting picked at "
             "random gets), minus the script's defaults', minus the best setting's and minus a round robin's over "
             "the same values (the control that takes them in turn without a bandit), each difference with a 95% "
             "interval from resampling the two sides' seeds independently (the best setting held as ranked), and "
             "their cost in runs of "
             f"{budget:,} steps per seed (a grid search costs one run per setting). The best setting is chosen on "
             "the seeds it is scored on, so it is optimistic; the last column of the settings table chooses it on "
             "the other seeds instead (leave one seed out), what a grid search could expect.", ""]
    for env, grid in found.items():
        defaults = defaults_of(grid, benchmark)
        median = float(np.median([s.final for s in grid]))
        settings = {id(r) for s in grid for r in s.runs}
        others = [r for r in runs if r.env_id == env and id(r) not in settings and r.raw_score is not None]
        labels = list(dict.fromkeys(r.label for r in others))
        marks = {label: float(np.mean([r.raw_score for r in others if r.label == label])) for label in labels}
        methods = {label: ([r.raw_score for r in others if r.label == label],
                           [a for a in (normalized_area(r) for r in others if r.label == label) if a is not None])
                   for label in labels}
        name = landscape_figure(env, grid, methods, defaults, benchmark, out)
        gains = gains_with_intervals(grid, defaults, seed, reps)
        failed = failing(grid)
        chosen = best_chosen_on_other_seeds(grid)
        areas = [s for s in grid if s.area is not None]
        lines += [f"#### {env}", "", f"![landscape of fixed settings on {env}]({name})", "",
                  f"{len(grid)} settings; best {number(grid[0].final)} ({grid[0].text()}), median {number(median)}, "
                  f"worst {number(grid[-1].final)} ({grid[-1].text()})"
                  + (f"; the defaults ({defaults.text()}) rank {grid.index(defaults) + 1} of {len(grid)} at "
                     f"{number(defaults.final)}" if defaults else "; the defaults are not among them")
                  + (f"; the best setting chosen on the other seeds scores {number(chosen)}" if chosen is not None
                     else "")
                  + (f". By area under the curve the best is {max(areas, key=lambda s: s.area).text()} "
                     f"({max(s.area for s in areas):.2f}), the defaults "
                     f"{'–' if defaults is None or defaults.area is None else f'{defaults.area:.2f}'}."
                     if areas else "."),
                  "",
                  "What tuning gains (mean final score; 95% interval from resampling each setting's seeds): "
                  + "; ".join(f"{what} {signed(point)} [{signed(low)}, {signed(high)}]" for what, (point, low, high)
                              in gains.items()) + ". "
                  + ("Settings with a failed seed (below half the best mean): "
                     + "; ".join(f"{s.text()} ({', '.join(number(v) for v in s.finals.values())})" for s in failed)
                     if failed else "No setting has a failed seed (below half the best mean)."), ""]
        if not labels:
            continue
        rng = np.random.default_rng(seed)
        lines += ["| method | final score | percentile among the settings | − median setting | − defaults | "
                  "− best setting | − round robin on its values | runs per seed | settings its runs held longest "
                  "(rank of " + str(len(grid)) + ") |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for label in labels:
            members = [r for r in others if r.label == label]
            score = marks[label]
            held = [held_longest(r, keys) for r in members if r.kind == "ultho"]
            ranks = [rank_of(h, grid) for h in held if h is not None]
            held_text = ", ".join("–" if rank is None else str(rank) for rank in ranks) if ranks else "–"
            cost = float(np.mean([r.budget for r in members])) / budget
            references = [list(defaults.finals.values()) if defaults else [], list(grid[0].finals.values()),
                          [r.raw_score for r in round_robin_of(members, others)]]
            differences = " | ".join(difference_cell(members, reference, rng, reps) for reference in references)
            lines.append(f"| {label} | {number(score)} | {percentile(score, grid):.0f} | {signed(score - median)} | "
                         f"{differences} | {cost:.3g} | {held_text} |")
        lines.append("")
    return lines

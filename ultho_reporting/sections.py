"""The sections of report.md: for each benchmark, markdown text and tables around its figures.

``benchmark_section`` writes one benchmark's part, section by section: learning curves, scores per
environment, aggregate scores (whose rows also go to aggregate.csv), sample efficiency, the HPO baselines, the
decision process and confidence bounds, robustness over (c, W), the paper's best-(c, W) protocol on both
sides (``protocol.py``) and the landscape of fixed settings (``landscape.py``). Each section is a function of
the benchmark's runs that returns its lines (none when it has nothing to show), so a new section is one more
function and one more line in ``benchmark_section``.
"""

import os
from dataclasses import dataclass

import numpy as np

from ultho_reporting.decisions import exploration_ratio
from ultho_reporting.figures import (BAND_LINES, decision_figures, efficiency_figure, learning_curves,
                                     method_groups, method_styles, per_run_figure, robustness_figure,
                                     schedule_figure, slug)
from ultho_reporting.landscape import landscape_section
from ultho_reporting.protocol import protocol_section
from ultho_reporting.references import BENCHMARKS, NORMALIZATION
from ultho_reporting.runs import (HPO_METHODS, Run, Study, algorithm_prefix, baseline_of, fixed_settings,
                                  method_order)
from ultho_reporting.scores import (AGGREGATES, aggregate_with_interval, better_of_two, coverage_groups, efficiency_of,
                                    normalized_area, strata_of)

AGGREGATE_COLUMNS = ["benchmark", "method", "environments", "games", "runs", "mean", "mean_low", "mean_high", "iqm",
                     "iqm_low", "iqm_high", "budget_steps_min", "budget_steps_max", "normalization"]
"""aggregate.csv's columns: one row per method and group of environments of the aggregate tables."""


@dataclass(frozen=True)
class Options:
    """What the command line decides for every section."""

    out: str  # the folder of report.md, where the figures go
    seed: int  # of every bootstrap
    reps: int  # bootstrap resamples
    solve_threshold: float  # the running score that counts as solved (sample efficiency)
    solve_window: int  # logged iterations the running score averages
    per_run: bool  # a decision figure for every ULTHO run too


# ---------------------------------------------------------------------- numbers in tables
def percent(point: float, low: float, high: float) -> str:
    return f"{100 * point:.1f} [{100 * low:.1f}, {100 * high:.1f}]"


def number(value: float) -> str:
    """A raw score in the per-environment tables: three significant digits, at least two decimals."""
    return f"{value:.2f}" if abs(value) < 100 else f"{value:,.0f}"


def mean_with_interval(values: list[float], seed: int, reps: int, count: str | None = None) -> str:
    """``mean [low, high] (n)``: a percentile bootstrap interval of the mean over seeds; ``count`` in place of n."""
    if not values:
        return "–"
    point, low, high = aggregate_with_interval([np.array(values)], "mean", seed, reps)
    return f"{number(point)} [{number(low)}, {number(high)}] ({count or len(values)})"


def count_with_diverged(counted: list[Run], left_out: list[Run]) -> str:
    """A table cell's run count, saying how many of its runs diverged ("3, 1 diverged") and how many runs that
    diverged the cell leaves out for want of a value ("2; 1 diverged left out": no evaluation)."""
    diverged = sum(r.diverged is not None for r in counted)
    text = f"{len(counted)}" + (f", {diverged} diverged" if diverged else "")
    missing = sum(r.diverged is not None for r in left_out)
    return text + (f"; {missing} diverged left out" if missing else "")


def budget_text(runs: list[Run]) -> str:
    low, high = min(r.budget for r in runs), max(r.budget for r in runs)
    return f"{low:,}" if low == high else f"{low:,}–{high:,}"


# ---------------------------------------------------------------------- one benchmark
def benchmark_section(study: Study, benchmark: str, options: Options) -> tuple[list[str], list[dict]]:
    """The part of report.md on one benchmark, and its rows of aggregate.csv."""
    with_grid = [r for r in study.runs if r.benchmark == benchmark]
    runs = [r for r in with_grid if not r.grid]  # a sweep's grid of fixed settings has a section of its own
    methods = method_order(runs)
    styles = method_styles(runs)
    lines = [f"## {BENCHMARKS[benchmark]}", ""]
    lines += curves_section(runs, benchmark, styles, options)
    lines += scores_section(runs, benchmark, methods, options)
    aggregate_lines, rows = aggregate_section(runs, benchmark, methods, options)
    lines += aggregate_lines
    lines += efficiency_section(runs, benchmark, methods, styles, options)
    lines += hpo_section(runs, benchmark, methods, options)
    lines += decisions_section(runs, benchmark, methods, study.runs, options)
    lines += robustness_section(runs, benchmark, study.grid, options)
    lines += protocol_section(runs, benchmark, options.seed, options.reps)
    lines += landscape_section(with_grid, benchmark, options.out, number, options.seed, options.reps)
    return lines, rows


def curves_section(runs: list[Run], benchmark: str, styles: dict, options: Options) -> list[str]:
    groups = method_groups(runs)
    drawn = [(group, learning_curves(runs, benchmark, styles, group, options.out)) for group in groups]
    lines = ["### Learning curves", ""]
    if not any(name for _, name in drawn):
        return lines + ["No run has TensorBoard return curves.", ""]
    for group, name in drawn:
        if name and group.key:
            lines += [f"Learning curves of {group.what}:", ""]
        if name:
            lines += [f"![learning curves]({name})", ""]
    return lines + ["Episodic return of the training episodes against environment steps; the line is the mean "
                    "over seeds, the band one standard deviation (drawn for the baseline alone in a panel of more "
                    f"than {BAND_LINES} lines). Each method keeps one colour and line style in every figure; "
                    "Relay-ULTHO is dashed in the colour of the ULTHO point it relays and shows the winning "
                    "COI/NOI run."
                    + (f" {len(method_order(runs))} methods are too many for one figure: the first shows the paper's "
                       "protocol, the others each group beside the baseline." if len(groups) > 1 else ""), ""]


def environments(runs: list[Run]) -> list[str]:
    """The columns of the per-environment tables."""
    return sorted({r.env_id for r in runs})


def per_environment_table(runs: list[Run], methods: list[str], envs: list[str], value, seed: int,
                          reps: int) -> list[str]:
    lines = ["| method | " + " | ".join(envs) + " |", "|---|" + "---|" * len(envs)]
    for label in methods:
        cells = []
        for env in envs:
            members = [r for r in runs if r.label == label and r.env_id == env]
            counted = [r for r in members if value(r) is not None]
            left_out = [r for r in members if value(r) is None]
            count = count_with_diverged(counted, left_out)
            cells.append(mean_with_interval([value(r) for r in counted], seed, reps, count) if counted else
                         f"– ({count})" if any(r.diverged is not None for r in left_out) else "–")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + [""]


def diverged_list(runs: list[Run], methods: list[str]) -> list[str]:
    """Every entry scored by a run that diverged, with where it stopped."""
    diverged = sorted((r for r in runs if r.diverged is not None),
                      key=lambda r: (methods.index(r.label), r.env_id, r.seed, r.path))
    if not diverged:
        return []
    lines = ["Diverged: the loss of these runs became non-finite and they stopped there. Each counts as a finished "
             "run in every table, with the final score it had reached (the mean return of its last 100 training "
             "episodes), and has no evaluation score.", ""]
    for r in diverged:
        where = r.diverged
        lines.append(f"- `{r.path}` ({r.label}, {r.env_id}, seed {r.seed}): non-finite {where['what']} at iteration "
                     f"{where['iteration']:,}, step {where['global_step']:,}"
                     + (" (its winning run)" if r.kind == "relay" else " (its best trial)" if r.study else ""))
    return lines + [""]


def scores_section(runs: list[Run], benchmark: str, methods: list[str], options: Options) -> list[str]:
    envs = environments(runs)
    lines = ["### Scores per environment", "",
             f"{'Test score' if benchmark == 'procgen' else 'Final score'}: "
             + ("mean return on the full level distribution (the paper's Procgen measure). " if benchmark == "procgen"
                else "mean return of the last 100 training episodes (the paper's measure). ")
             + "Each cell: mean over seeds [95% percentile-bootstrap interval] (number of runs), raw returns; "
             "Relay-ULTHO is scored by its winning run.", ""]
    lines += per_environment_table(runs, methods, envs, lambda r: r.raw_score, options.seed, options.reps)
    lines += ["Evaluation score: mean return of fresh episodes of the final policy on environment seeds never used "
              "in training (`summary.json`'s `eval`).", ""]
    lines += per_environment_table(runs, methods, envs, lambda r: r.eval_score, options.seed, options.reps)
    return lines + diverged_list(runs, methods)


def aggregate_section(runs: list[Run], benchmark: str, methods: list[str],
                      options: Options) -> tuple[list[str], list[dict]]:
    """The aggregate tables, one per group of environments that methods cover (``coverage_groups``), and their
    rows of aggregate.csv."""
    seed, reps = options.seed, options.reps
    normalization = NORMALIZATION[benchmark]
    lines = ["### Aggregate scores", "", f"Score: {normalization}. Mean and IQM (interquartile mean) over "
             f"environments x seeds, 95% stratified-bootstrap percentile intervals ({reps} resamples of the seeds "
             f"within each environment, seed {seed}). Each table compares only methods with runs on every one of its "
             "environments. "
             + ("Relay-ULTHO: one score per relay (its winner's); its budget is the three runs'. "
                if any(r.kind == "relay" for r in runs) else "")
             + ("PBT, PB2, random search: one score per study, the final score of its best trial; its budget is "
                "the whole population's steps. " if any(r.kind in HPO_METHODS for r in runs) else "")
             + "Also in [aggregate.csv](aggregate.csv).", ""]
    rows = []
    for group_envs, group_methods in coverage_groups(runs, methods):
        lines += [f"Over {len(group_envs)} environment{'s' * (len(group_envs) > 1)}: {', '.join(group_envs)}.", "",
                  "| method | environments | runs | mean (%) [95% CI] | IQM (%) [95% CI] "
                  "| budget per run or study (steps) |",
                  "|---|---|---|---|---|---|"]
        for label in group_methods:
            members = [r for r in runs if r.label == label]
            strata = strata_of(members, set(group_envs))
            mean, iqm = (aggregate_with_interval(strata, name, seed, reps) for name in AGGREGATES)
            count = sum(map(len, strata))
            diverged = sum(r.diverged is not None and r.score is not None and r.env_id in group_envs for r in members)
            lines.append(f"| {label} | {len(strata)} | {count}{f' ({diverged} diverged)' if diverged else ''} | "
                         f"{percent(*mean)} | {percent(*iqm)} | {budget_text(members)} |")
            rows.append({"benchmark": benchmark, "method": label, "environments": " ".join(group_envs),
                         "games": len(strata), "runs": count, "mean": mean[0], "mean_low": mean[1],
                         "mean_high": mean[2], "iqm": iqm[0], "iqm_low": iqm[1], "iqm_high": iqm[2],
                         "budget_steps_min": min(r.budget for r in members),
                         "budget_steps_max": max(r.budget for r in members), "normalization": normalization})
        lines.append("")
    notes = sorted({f"`{r.path}`: {r.score_note}" for r in runs if r.score_note})
    lines += [f"- {n}" for n in notes] + [""] * bool(notes)
    return lines, rows


def efficiency_section(runs: list[Run], benchmark: str, methods: list[str], styles: dict,
                       options: Options) -> list[str]:
    """Steps to solve per method and environment, the runs-solved figures, and the areas under the curves."""
    threshold, window = options.solve_threshold, options.solve_window
    figures = [(group, efficiency_figure(runs, benchmark, styles, group, threshold, window, options.out))
               for group in method_groups(runs)]
    figures = [(group, name) for group, name in figures if name]
    if not figures:
        return []
    envs = environments(runs)
    relays = any(r.kind == "relay" for r in runs)
    ppo = [r for r in runs if r.kind == "ppo"]
    # Fixed settings selected as a relay selects needs two seeds of one environment to choose from.
    paired = relays and len(ppo) > len({r.env_id for r in ppo})
    baseline = baseline_of(benchmark)
    short = any(r.curve is not None and len(r.curve) < window for r in runs)
    lines = ["### Sample efficiency", "",
             f"Steps to solve: the first environment step at which a run's running score (the mean of its last "
             f"{window} logged training returns, each the mean return of the episodes that ended in one "
             f"iteration, on the scale above) reaches {threshold:g}. Each cell: the mean over runs, a run that "
             "never reached it counted with its whole budget (then the mean is a lower bound, marked ≥), and "
             "(runs that reached it / runs)."
             + (f" A run that logged fewer than {window} returns has a running score only at its last logged step: "
                "the mean of all its returns." if short else "")
             + (" Relay-ULTHO: its winning run, from that run's start; the last column counts from the relay's "
                "start instead, its full ULTHO run's steps included (the COI and NOI runs side by side)."
                if relays else "")
             + (f" {baseline}, better of 2 seeds: fixed {baseline} selected as a relay selects, the run with "
                "the higher final score of every pair of seeds on an environment (all pairs), scored by that run."
                if paired else ""), "",
             "| method | " + " | ".join(envs) + " | all |" + (" all, from the relay's start |" if relays else ""),
             "|---|" + "---|" * (len(envs) + 1 + relays)]
    rows_of = [(label, [r for r in runs if r.label == label]) for label in methods]
    if paired:
        rows_of.insert(methods.index(baseline) + 1, (f"{baseline}, better of 2 seeds", better_of_two(ppo)))
    for label, members in rows_of:
        cells = [efficiency_of([r for r in members if r.env_id == env], threshold, window).text() for env in envs]
        cells.append(efficiency_of(members, threshold, window).text())
        if relays:
            cells.append(efficiency_of(members, threshold, window, from_start=True).text())
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("")
    for group, name in figures:
        lines += ([f"Runs solved, {group.what}:", ""] if group.key else []) + [f"![sample efficiency]({name})", ""]
    if paired:
        selected = [(label, [r.score for r in members if r.score is not None]) for label, members in rows_of
                    if label in (baseline, f"{baseline}, better of 2 seeds") or members[0].kind == "relay"]
        lines += ["Final score of the scored runs (mean over runs, on the scale above): "
                  + "; ".join(f"{label} {100 * np.mean(scores):.1f}%" for label, scores in selected if scores)
                  + ".", ""]
    return lines + areas_table(rows_of, envs, options)


def areas_table(rows_of: list[tuple[str, list[Run]]], envs: list[str], options: Options) -> list[str]:
    """The area under each run's normalized learning curve divided by its length, per row of the efficiency
    table and environment."""
    areas = [(label, [r for r in members if normalized_area(r) is not None]) for label, members in rows_of]
    if not any(members for _, members in areas):
        return []
    lines = ["Area under the normalized learning curve divided by its length (the mean score over training; "
             "1.0 = the reference all along). Each cell: mean over runs [95% percentile-bootstrap interval] "
             "(runs).", "", "| method | " + " | ".join(envs) + " | all |", "|---|" + "---|" * (len(envs) + 1)]
    for label, members in areas:
        cells = [mean_with_interval([normalized_area(r) for r in members if r.env_id == env], options.seed,
                                    options.reps) for env in envs]
        cells.append(mean_with_interval([normalized_area(r) for r in members], options.seed, options.reps))
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + [""]


def hpo_section(runs: list[Run], benchmark: str, methods: list[str], options: Options) -> list[str]:
    """One row per HPO study and the settings schedule of each study's best trial."""
    studies = sorted((r for r in runs if r.kind in HPO_METHODS), key=lambda r: (methods.index(r.label), r.env_id,
                                                                               r.seed))
    if not studies:
        return []
    lines = ["### HPO baselines", "",
             "One row per study (`hpo_baselines.py`): the budget is every trial's steps together; the best "
             "trial's final score is what the tables above use; the maximum observed score (the highest score "
             "any trial reported at any interval) is the paper's measure for population methods.", "",
             "| method | environment | seed | budget (steps) | best trial | its final score | maximum observed "
             "score (trial, step) | exploits |", "|---|---|---|---|---|---|---|---|"]
    for r in studies:
        seen = r.study["max_observed_score"]
        lines.append(f"| {r.label} | {r.env_id} | {r.seed} | {r.budget:,} | {r.study['best_trial']} | "
                     f"{number(r.raw_score) if r.raw_score is not None else '–'} | {number(seen['score'])} "
                     f"({seen['trial']}, {seen['step']:,}) | {len(r.study.get('exploits') or [])} |")
    lines.append("")
    schedule = schedule_figure(runs, benchmark, options.out)
    if schedule:
        lines += [f"![settings schedules]({schedule})", "",
                  "The settings behind each study's best final network (PBT and PB2 follow every exploit back "
                  "into the trial it copied; random search keeps one setting) on the first environment with "
                  "studies: one column per method, one row per cluster, each seed in its own colour and line "
                  "style (drawn a hair apart, so that seeds holding the same value stay visible); the last "
                  "column, for comparison, the value in force at each iteration of one ULTHO run (the paper's "
                  "(c, W) = (5, 10) where it ran, its lowest seed).", ""]
    return lines


def decisions_section(runs: list[Run], benchmark: str, methods: list[str], all_runs: list[Run],
                      options: Options) -> list[str]:
    """Per ULTHO method: its decision-process and bound figures, its selection tables, and with
    ``options.per_run`` a figure per run (named by its path below the folder every run of ``all_runs`` shares)."""
    ultho_methods = [m for m in methods if any(r.label == m and r.kind == "ultho" for r in runs)]
    if not ultho_methods:
        return []
    baseline = baseline_of(benchmark)
    lines = ["### Decision process and confidence bounds", "",
             "The decision figures have one row per environment: left, each cluster's cumulative share of the "
             "selections so far (mean over the environment's runs), or with a search space of one cluster a strip "
             "per run of the value it chose, each stretch of a few iterations split by the share of each value; "
             "middle, the share of each value among its "
             "cluster's selections; right, the share of the logged iterations each value was in force (a "
             "cluster the bandit stopped choosing keeps its last value, one it never chose the script's "
             "setting), both pooled over the environment's runs. The hatched bar with the value in bold is "
             f"{baseline}'s own setting, the one its fixed-settings runs used, so that a run that held "
             f"{baseline}'s settings shows as tall hatched bars on the right. Bounds, one panel per environment "
             "(each in its critic's units): each cluster's utility U (mean of its last W credits, Eq. 6) and "
             "U + c·sqrt(ln i / N), the bound Eq. 4 maximises, mean over runs; lines that coincide (as those of "
             "clusters the bandit never chose can) are drawn once in grey and named. The tables: the "
             "credited selections of each value, pooled over the runs; then each cluster's share of them on each "
             "environment, pooled over its runs (in brackets "
             "the lowest and highest share of a single run), and the bonus / utility spread: over the second "
             "half of each run, the median of the clusters' mean UCB bonus c·sqrt(ln i / N) divided by the "
             "spread of their utilities in the bound's units, the median over the runs; above 1 the bonus "
             "outweighs what separates the clusters and they are taken in turn, well below 1 the bandit "
             "follows the utilities (– for strategies without a bonus). Last, per run, the value each cluster "
             "held for the most iterations and the share of the iterations it held it (a cluster the bandit "
             "stopped choosing keeps the value it was last given), beside the run's final score.", ""]
    for label in ultho_methods:
        members = [r for r in runs if r.label == label]
        drawn = decision_figures(members, f"{BENCHMARKS[benchmark]} {label}", options.out,
                                 slug(f"{benchmark}_{label}"), fixed_settings(all_runs, benchmark), baseline)
        lines += [f"#### {label}", ""] + [f"![{what}]({name})" for what, name in drawn] + [""]
        lines += selection_table(members) + [""]
        lines += decisions_by_environment(members) + [""]
        lines += settings_in_force(members) + [""]
        if not options.per_run:
            continue
        # Named by the path below the directory all runs share, so names stay short and distinct.
        base = os.path.commonpath([os.path.dirname(os.path.abspath(r.path)) for r in all_runs])
        per_run = [(r, per_run_figure(r, os.path.relpath(os.path.abspath(r.path), base), options.out))
                   for r in sorted(members, key=lambda r: (r.env_id, r.seed))]
        lines += ["Per run: " + ", ".join(f"[{r.env_id} seed {r.seed}]({name})" for r, name in per_run if name), ""]
    return lines


def selection_table(runs: list[Run]) -> list[str]:
    """The credited selections of each value (summary.json), pooled over the runs, and how many runs credited
    every value equally often, to within one (a strict rotation: the bandit's choices did not depend on its credits;
    within one, because a rotation stopped mid-cycle, as 975 choices between two values must be, ends uneven)."""
    counted = [r for r in runs if r.value_selections]
    if not counted:
        return []
    space = counted[0].search_space
    pooled = {cluster: np.sum([r.value_selections[cluster] for r in counted], axis=0) for cluster in space}
    total = sum(counts.sum() for counts in pooled.values())
    rotations = sum(max(counts := [n for values in r.value_selections.values() for n in values]) - min(counts) <= 1
                    for r in counted)
    lines = ["| cluster | credited selections (share) | per value |", "|---|---|---|"]
    for cluster, values in space.items():
        counts = pooled[cluster]
        lines.append(f"| {cluster} | {counts.sum():,} ({100 * counts.sum() / total:.1f}%) | "
                     + ", ".join(f"{v:g}: {n:,}" for v, n in zip(values, counts)) + " |")
    return lines + ["", f"Pooled over {len(counted)} runs. Runs that credited every value equally often, to within "
                        f"one (a strict rotation): {rotations} of {len(counted)}."]


def decisions_by_environment(runs: list[Run]) -> list[str]:
    """Per environment: each cluster's share of the credited selections (pooled over seeds, with the range over
    the seeds) and the exploration ratio (median over the seeds)."""
    counted = [r for r in runs if r.value_selections]
    envs = sorted({r.env_id for r in counted})
    if not envs:
        return []
    space = counted[0].search_space
    lines = ["| environment | runs | " + " | ".join(f"{cluster} (%)" for cluster in space)
             + " | bonus / utility spread |", "|---|---|" + "---|" * (len(space) + 1)]
    for env in envs:
        members = [r for r in counted if r.env_id == env]
        counts = np.array([[sum(r.value_selections[cluster]) for cluster in space] for r in members], dtype=float)
        shares = counts / counts.sum(1, keepdims=True)
        pooled = counts.sum(0) / counts.sum()
        ratios = [x for x in map(exploration_ratio, members) if x is not None]
        lines.append(f"| {env} | {len(members)} | "
                     + " | ".join(f"{100 * p:.1f} ({100 * lo:.0f}–{100 * hi:.0f})"
                                  for p, lo, hi in zip(pooled, shares.min(0), shares.max(0)))
                     + f" | {f'{np.median(ratios):.2f}' if ratios else '–'} |")
    return lines


def settings_in_force(runs: list[Run]) -> list[str]:
    """Per run, the value each cluster held for the most logged iterations (``hparams/*``) and that share: a
    cluster the bandit stopped choosing keeps the value it was last given."""
    logged = sorted((r for r in runs if r.search_space and all(f"hparams/{c}" in r.series for c in r.search_space)),
                    key=lambda r: (r.env_id, r.seed))
    if not logged:
        return []
    space = logged[0].search_space
    lines = ["| environment | seed | " + " | ".join(space) + " | final score |",
             "|---|---|" + "---|" * (len(space) + 1)]
    for run in logged:
        cells = []
        for cluster in space:
            values, counts = np.unique(run.series[f"hparams/{cluster}"][:, 1], return_counts=True)
            cells.append(f"{values[counts.argmax()]:g} ({100 * counts.max() / counts.sum():.0f}%)")
        lines.append(f"| {run.env_id} | {run.seed} | " + " | ".join(cells)
                     + f" | {number(run.raw_score) if run.raw_score is not None else '–'} |")
    return lines


def robustness_section(runs: list[Run], benchmark: str, grid: dict, options: Options) -> list[str]:
    robustness, empty, single = robustness_figure(runs, benchmark, grid, options.seed, options.reps, options.out)
    ultho = algorithm_prefix(benchmark, "ULTHO") + "ULTHO"
    points = sorted({(c, window) for _, c, window in single})
    one_point = (f"(c={points[0][0]:g}, W={points[0][1]}) on each environment" if len(points) == 1 else
                 "on each environment: " + ", ".join(f"{env} (c={c:g}, W={window})" for env, c, window in single))
    if not robustness:
        return (["### Robustness over (c, W)", "",
                 f"No figure: {ultho} ran at one (c, W) point {one_point}, so there is nothing to compare across "
                 "(c, W); its scores are in the tables above.", ""] if single else [])
    return ["### Robustness over (c, W)", "", f"![robustness]({robustness})", "",
            "Mean score of ULTHO at each (c, W) of each environment with its 95% percentile-bootstrap interval "
            "over seeds; the dashed line and grey band are fixed-settings "
            f"{baseline_of(benchmark)} on that environment. Every panel has the same y range, so that a "
            "difference looks as large as it is on every environment."
            + (f" No scored ULTHO runs at {', '.join(empty)}." if empty else "")
            + (" Not drawn, with one (c, W) point each: "
               + ", ".join(f"{env} (c={c:g}, W={window})" for env, c, window in single) + "." if single else ""), ""]


def missing_section(study: Study) -> list[str]:
    """What a sweep, relay or study lacked and every input skipped, at the end of report.md."""
    if not (study.missing or study.warnings):
        return []
    return (["## Missing and skipped", ""] + [f"- {m}" for m in study.missing]
            + [f"- {w}" for w in study.warnings] + [""])

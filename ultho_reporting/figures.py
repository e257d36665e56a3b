"""The report's figures, drawn with matplotlib into PNG files.

Each function draws one figure of a benchmark (learning curves, runs solved, a method's decision process and
confidence bounds, one run's decisions, the HPO studies' settings schedules, robustness over (c, W)), saves it
into the report's folder and returns its file name for report.md, or None when there is nothing to draw.
Curves of several runs are averaged on a common grid of steps.
"""

import os
import re

import matplotlib

matplotlib.use("Agg")  # headless: figures go to files only
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import EngFormatter

from ultho_reporting.decisions import bounds, cumulative_shares, value_counts
from ultho_reporting.references import BENCHMARKS, reference_of
from ultho_reporting.runs import HPO_METHODS, PAPER_VARIANT, Run, baseline_of, method_order
from ultho_reporting.scores import aggregate_with_interval, efficiency_of, strata_of

GRID_POINTS = 200
STEPS = EngFormatter(sep="")


def on_common_grid(series: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """Series (T, 1 + K) of (step, values...) interpolated onto steps shared by all: (grid, (R, G, K))."""
    series = [s for s in series if s is not None and len(s)]
    if not series:
        return None
    start, stop = max(s[0, 0] for s in series), min(s[-1, 0] for s in series)
    grid = np.linspace(start, stop, GRID_POINTS) if stop > start else np.array([stop])
    values = [np.stack([np.interp(grid, s[:, 0], s[:, k]) for k in range(1, s.shape[1])], axis=-1) for s in series]
    return grid, np.stack(values)


def slug(text: str) -> str:
    """A file name made of a method's label or a run's path."""
    return re.sub(r"[^A-Za-z0-9.]+", "_", text).strip("_")


def method_colors(methods: list[str]) -> dict:
    """One colour per method, the same in every figure of a benchmark."""
    palette = plt.get_cmap("tab10" if len(methods) <= 10 else "tab20")
    return {label: palette(i) for i, label in enumerate(methods)}


def save(figure: plt.Figure, out: str, name: str) -> str:
    figure.savefig(os.path.join(out, name), dpi=90)
    plt.close(figure)
    return name


def steps_axis(axes: plt.Axes) -> None:
    axes.xaxis.set_major_formatter(STEPS)
    axes.set_xlabel("environment steps")


def env_panels(count: int, width: float = 4.2, height: float = 3.2) -> tuple[plt.Figure, list[plt.Axes]]:
    """A figure with one panel per environment, at most four a row; unused panels hidden."""
    columns = min(4, count)
    rows = -(-count // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(max(7.5, width * columns), height * rows + 0.8),
                                squeeze=False, layout="constrained")
    for panel in axes.flat[count:]:
        panel.set_visible(False)
    return figure, list(axes.flat[:count])


def method_legend(figure: plt.Figure, methods: list[str], colors: dict) -> None:
    lines = [plt.Line2D([], [], color=colors[label]) for label in methods]
    figure.legend(lines, methods, loc="outside lower center", ncol=min(len(lines), 4), frameon=False)


def learning_curves(runs: list[Run], benchmark: str, colors: dict, out: str) -> str | None:
    envs = sorted({r.env_id for r in runs if r.curve is not None})
    if not envs:
        return None
    figure, panels = env_panels(len(envs))
    for panel, env_id in zip(panels, envs):
        for label in method_order(runs):
            grid = on_common_grid([r.curve for r in runs if r.env_id == env_id and r.label == label])
            if grid is None:
                continue
            steps, values = grid
            mean, std = values[..., 0].mean(0), values[..., 0].std(0)
            panel.plot(steps, mean, color=colors[label], label=label, marker="o" if len(steps) == 1 else None)
            panel.fill_between(steps, mean - std, mean + std, color=colors[label], alpha=0.2)
        panel.set_title(env_id, fontsize=10)
        panel.set_ylabel("episodic return")
        steps_axis(panel)
        panel.grid(alpha=0.3)
    method_legend(figure, method_order(runs), colors)
    figure.suptitle(f"{BENCHMARKS[benchmark]}: training return (mean ± std over seeds)")
    return save(figure, out, f"curves_{benchmark}.png")


def efficiency_figure(runs: list[Run], benchmark: str, colors: dict, threshold: float, window: int,
                      out: str) -> str | None:
    """Per environment, the share of each method's runs whose running score has reached the threshold by step t."""
    envs = sorted({r.env_id for r in runs if r.curve is not None and reference_of(benchmark, r.env_id)})
    if not envs:
        return None
    figure, panels = env_panels(len(envs))
    for panel, env_id in zip(panels, envs):
        for label in method_order(runs):
            members = [r for r in runs if r.env_id == env_id and r.label == label and r.curve is not None]
            if not members:
                continue
            found = efficiency_of(members, threshold, window)
            horizon = max(found.budgets)
            reached = sorted(s for s in found.steps if s is not None)
            steps = [0.0, *reached, float(horizon)]
            shares = [0.0, *(np.arange(1, len(reached) + 1) / len(members)), len(reached) / len(members)]
            panel.step(steps, 100 * np.array(shares), where="post", color=colors[label], label=label)
        panel.set_title(env_id, fontsize=10)
        panel.set_ylabel("runs solved (%)")
        panel.set_ylim(-3, 103)
        steps_axis(panel)
        panel.grid(alpha=0.3)
    method_legend(figure, method_order(runs), colors)
    figure.suptitle(f"{BENCHMARKS[benchmark]}: runs solved (running score ≥ {threshold:g})")
    return save(figure, out, f"efficiency_{benchmark}.png")


def decision_panels(share_axes: plt.Axes, value_axes: plt.Axes, runs: list[Run]) -> bool:
    space = runs[0].search_space
    grid = on_common_grid([cumulative_shares(r) for r in runs])
    if grid is None:
        return False
    steps, shares = grid
    share_axes.stackplot(steps, (100 * shares.mean(0)).T, labels=list(space), alpha=0.85)
    share_axes.set_ylim(0, 100)
    share_axes.set_ylabel("cumulative share of selections (%)")
    share_axes.set_title("inter-cluster: which cluster is chosen", fontsize=10)
    steps_axis(share_axes)
    share_axes.legend(loc="upper center", bbox_to_anchor=(0.5, -0.22),
                      ncol=len(space), frameon=False, fontsize=8)
    counts = value_counts(runs)
    position, ticks, names = 0, [], []
    for k, (cluster, values) in enumerate(space.items()):
        total = counts[k].sum()
        shares_in = 100 * counts[k, :len(values)] / total if total else np.zeros(len(values))
        xs = position + np.arange(len(values))
        value_axes.bar_label(value_axes.bar(xs, shares_in, color=f"C{k}", alpha=0.85), fmt="%.0f", fontsize=7)
        value_axes.text(xs.mean(), -0.16, cluster, transform=value_axes.get_xaxis_transform(), ha="center",
                        fontsize=9, color=f"C{k}")
        ticks += list(xs)
        names += [f"{v:g}" for v in values]
        position += len(values) + 1
    value_axes.set_xticks(ticks, names, fontsize=8)
    value_axes.set_ylim(0, 110)
    value_axes.set_ylabel("share within its cluster (%)")
    value_axes.set_title("intra-cluster: which value is chosen", fontsize=10)
    return True


def bound_panel(axes: plt.Axes, runs: list[Run]) -> bool:
    grid = on_common_grid([bounds(r) for r in runs])
    if grid is None:
        return False
    steps, values = grid
    mean = values.mean(0)
    for k, cluster in enumerate(runs[0].search_space):
        axes.plot(steps, mean[:, 2 * k], color=f"C{k}", label=f"{cluster}: utility U")
        axes.plot(steps, mean[:, 2 * k + 1], color=f"C{k}", linestyle="--", label=f"{cluster}: U + bonus")
    axes.set_ylabel("utility (critic value units)")
    axes.set_title("cluster utility (solid) and upper confidence bound (dashed)", fontsize=10)
    steps_axis(axes)
    axes.grid(alpha=0.3)
    axes.legend(loc="upper center", bbox_to_anchor=(0.5, -0.22), ncol=2, frameon=False, fontsize=8)
    return True


def decision_figures(runs: list[Run], title: str, out: str, name: str) -> list[tuple[str, str]]:
    """The aggregated decision-process and confidence-bound figures: [(what, file name)] of those drawn."""
    drawn = []
    plural = f"{len(runs)} run{'s' * (len(runs) > 1)}"
    figure, (shares, values) = plt.subplots(1, 2, figsize=(11, 4.2), layout="constrained")
    figure.suptitle(f"{title}: decision process, {plural}")
    if decision_panels(shares, values, runs):
        drawn.append(("decision process", save(figure, out, f"decision_{name}.png")))
    figure, axes = plt.subplots(figsize=(7, 4.6), layout="constrained")
    figure.suptitle(f"{title}: confidence bounds, mean over {plural}")
    if bound_panel(axes, runs):
        drawn.append(("confidence bounds", save(figure, out, f"bounds_{name}.png")))
    plt.close("all")
    return drawn


def per_run_figure(run: Run, name: str, out: str) -> str | None:
    figure, ax = plt.subplots(1, 3, figsize=(16, 4.4), layout="constrained")
    drawn = decision_panels(ax[0], ax[1], [run])
    drawn = bound_panel(ax[2], [run]) and drawn
    figure.suptitle(f"{os.path.basename(run.path)} ({run.label}, seed {run.seed})")
    if not drawn:
        plt.close(figure)
        return None
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    return save(figure, out, os.path.join("runs", f"{slug(name)}.png"))


def schedule_figure(runs: list[Run], benchmark: str, out: str) -> str | None:
    """Per cluster, the value in force against steps: every study's best-trial schedule and, for comparison,
    the ``hparams/*`` series of one ULTHO run per method on the same environment."""
    studies = [r for r in runs if r.kind in HPO_METHODS]
    env_id = sorted(r.env_id for r in studies)[0]
    studies = [r for r in studies if r.env_id == env_id]
    clusters = sorted({name for r in studies for _, _, settings in r.study["schedule"] for name in settings})
    if not clusters:
        return None
    figure, panels = plt.subplots(len(clusters), 1, figsize=(9, 2.4 * len(clusters) + 0.8), squeeze=False,
                                  layout="constrained", sharex=True)
    labels = method_order(runs)
    for panel, cluster in zip(panels[:, 0], clusters):
        for r in studies:
            steps, values = [], []
            for start, end, settings in r.study["schedule"]:
                steps += [start, end]
                values += [settings[cluster]] * 2
            panel.plot(steps, values, color=f"C{labels.index(r.label) % 10}", alpha=0.8, linewidth=1.5,
                       label=f"{r.label}, seed {r.seed}")
        for label in labels:
            ultho = sorted((r for r in runs if r.label == label and r.kind == "ultho" and r.env_id == env_id
                            and f"hparams/{cluster}" in r.series), key=lambda r: r.seed)
            if ultho:
                series = ultho[0].series[f"hparams/{cluster}"]
                panel.step(series[:, 0], series[:, 1], where="pre", color=f"C{labels.index(label) % 10}",
                           alpha=0.35, linewidth=0.8, label=f"{label}, seed {ultho[0].seed}")
        panel.set_ylabel(cluster)
        if cluster == "learning_rate":
            panel.set_yscale("log")
        panel.grid(alpha=0.3)
    steps_axis(panels[-1, 0])
    handles, names = panels[0, 0].get_legend_handles_labels()
    figure.legend(handles, names, loc="outside lower center", ncol=2, frameon=False, fontsize=8)
    figure.suptitle(f"{BENCHMARKS[benchmark]} {env_id}: settings schedules")
    return save(figure, out, f"schedules_{benchmark}.png")


def robustness_figure(runs: list[Run], benchmark: str, grid: dict, seed: int, reps: int,
                      out: str) -> tuple[str | None, list[str]]:
    """One panel per environment with ULTHO runs: the mean score at each (c, W) with its 95% interval, and the
    fixed-settings baseline.
    Returns (file name, the (c, W) cells of the sweeps' grids without scored runs)."""
    ultho = [r for r in runs if r.kind == "ultho" and r.score is not None and not r.narrowed
             and r.variant == PAPER_VARIANT]
    envs = sorted({r.env_id for r in ultho})
    if not envs:
        return None, []
    figure, panels = env_panels(len(envs), width=5.0, height=3.6)
    empty = []
    for panel, env_id in zip(panels, envs):
        here = [r for r in ultho if r.env_id == env_id]
        points = grid.get((benchmark, env_id), set()) | {(r.c, r.window) for r in here}
        cs, windows = sorted({c for c, _ in points}), sorted({w for _, w in points})
        width, labelled = 0.8 / len(cs), set()
        for i, c in enumerate(cs):
            for j, window in enumerate(windows):
                if (c, window) not in points:
                    continue
                x = j + (i - (len(cs) - 1) / 2) * width
                cell = strata_of([r for r in here if r.c == c and r.window == window])
                if not cell:
                    empty.append(f"{env_id} (c={c:g}, W={window})")
                    panel.text(x, 0.5, f"c = {c:g}: no runs", rotation=90, ha="center", va="center", fontsize=8,
                               color="gray", transform=panel.get_xaxis_transform())
                    continue
                point, low, high = (100 * v for v in aggregate_with_interval(cell, "mean", seed, reps))
                # Points, not bars: the cells often differ by less than a bar's height from zero shows.
                panel.errorbar(x, point, yerr=[[point - low], [high - point]], color=f"C{i}", capsize=4, marker="o",
                               linestyle="none", label=None if c in labelled else f"c = {c:g}")
                labelled.add(c)
        ppo = strata_of([r for r in runs if r.kind == "ppo" and r.env_id == env_id])
        if ppo:
            point, low, high = (100 * v for v in aggregate_with_interval(ppo, "mean", seed, reps))
            panel.axhline(point, color="black", linestyle="--", label=f"{baseline_of(benchmark)} (fixed settings)")
            panel.axhspan(low, high, color="black", alpha=0.08, zorder=0)
        panel.set_xticks(range(len(windows)), [f"W = {w}" for w in windows])
        panel.set_xlim(-0.5, len(windows) - 0.5)
        panel.set_title(env_id, fontsize=10)
        panel.set_ylabel("score (%), mean with 95% CI")
        panel.legend(loc="lower left", fontsize=7, framealpha=0.8)
    figure.suptitle(f"{BENCHMARKS[benchmark]}: ULTHO over (c, W), the sliding window W on the x axis", fontsize=11)
    return save(figure, out, f"robustness_{benchmark}.png"), empty

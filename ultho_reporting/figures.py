"""The report's figures, drawn with matplotlib into PNG files.

Each function draws one figure of a benchmark (learning curves, runs solved, a method's decision process and
confidence bounds, one run's decisions, the HPO studies' settings schedules, robustness over (c, W)), saves it
into the report's folder and returns its file name for report.md, or None when there is nothing to draw.
Curves of several runs are averaged on a common grid of steps.

Every figure is meant to be read in seconds: a benchmark with more methods than ``MAX_LINES`` draws its curves
in groups (``method_groups``: the paper's protocol, the (c, W) grid, the bandit variants, the HPO baselines),
each method keeps one colour and line style (``method_styles``) in every figure, the decision process and the
confidence bounds are drawn per environment, and the baseline's own setting of each cluster is marked.
"""

import os
import re
import textwrap
from dataclasses import dataclass

import matplotlib

matplotlib.use("Agg")  # headless: figures go to files only
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import EngFormatter, FixedLocator, FuncFormatter, NullLocator

from ultho_reporting.decisions import bounds, cumulative_shares, in_force, selections, value_counts
from ultho_reporting.references import BENCHMARKS, reference_of
from ultho_reporting.runs import HPO_METHODS, PAPER_VARIANT, Run, baseline_of, method_order, script_defaults
from ultho_reporting.scores import aggregate_with_interval, efficiency_of, strata_of

GRID_POINTS = 200
STEPS = EngFormatter(sep="")
MAX_LINES = 6
"""A figure of learning curves draws at most this many methods in one panel before they are split in groups."""
BAND_LINES = 3
"""A panel with more lines than this draws the ± std band of the baseline alone, so bands do not drown lines."""
PALETTE = [f"C{i}" for i in (0, 1, 2, 3, 4, 5, 6, 8, 9)] + ["#b8860b", "#008b8b", "#7b68ee", "#800000", "#9acd32"]
"""Colours of the methods other than the baseline (black), in order; tab10's grey is left out."""
SEED_STYLES = [("C0", "-"), ("C1", "--"), ("C2", ":"), ("C3", "-."), ("C4", "-"), ("C5", "--")]


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


def compact(value: float) -> str:
    """A setting's value as a short tick label: 3e-4, 2.5e-3, 0.01, 256."""
    value = float(value)
    if value != 0 and abs(value) < 0.01:
        exponent = int(np.floor(np.log10(abs(value))))
        return f"{value / 10 ** exponent:.3g}e{exponent}"
    return f"{value:g}"


def save(figure: plt.Figure, out: str, name: str) -> str:
    figure.savefig(os.path.join(out, name), dpi=90)
    plt.close(figure)
    return name


def steps_axis(axes: plt.Axes) -> None:
    axes.xaxis.set_major_formatter(STEPS)
    axes.set_xlabel("environment steps")


def env_panels(count: int, width: float = 4.2, height: float = 3.2,
               sharey: bool = False) -> tuple[plt.Figure, list[plt.Axes]]:
    """A figure with one panel per environment, at most four a row; unused panels hidden."""
    columns = min(4, count)
    rows = -(-count // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(max(7.5, width * columns), height * rows + 0.8),
                                squeeze=False, layout="constrained", sharey=sharey)
    for panel in axes.flat[count:]:
        panel.set_visible(False)
    return figure, list(axes.flat[:count])


# ---------------------------------------------------------------------- methods: styles and groups
@dataclass(frozen=True)
class Style:
    color: str
    linestyle: str = "-"


@dataclass(frozen=True)
class Group:
    """Methods drawn together in one figure of learning curves and one of runs solved."""

    key: str  # "" for the main figure (curves_<benchmark>.png), else the file name's suffix
    what: str  # the methods, in words, for titles and captions
    labels: list[str]
    envs: tuple[str, ...] | None = None  # only these environments (None: wherever its methods ran)
    by_c: bool = False  # one panel per environment and c: the (c, W) grid


def representatives(runs: list[Run]) -> dict[str, Run]:
    return {r.label: r for r in runs}


def paper_bandit(run: Run) -> bool:
    """ULTHO or Relay-ULTHO with the paper's bandit, on the benchmark's widest space, credited as by default."""
    return (run.kind in ("ultho", "relay") and run.variant == PAPER_VARIANT and not run.narrowed
            and run.utility == script_defaults(run.benchmark).get("ultho_utility", run.utility))


def method_groups(runs: list[Run]) -> list[Group]:
    """All methods in one group when there are at most ``MAX_LINES``; else the paper's protocol (the baseline,
    Relay-ULTHO and the paper's ULTHO at the (c, W) points it relays; without relays, at the points run on every
    environment the baseline ran), the whole (c, W) grid where it has more points (one panel per c), the bandit
    variants, and the HPO baselines, each beside the baseline."""
    labels = method_order(runs)
    if len(labels) <= MAX_LINES:
        return [Group("", "every method", labels)]
    rep = representatives(runs)
    baselines = [label for label in labels if rep[label].kind == "ppo"]
    envs = {r.env_id for r in runs if r.kind == "ppo"} or {r.env_id for r in runs}
    paper = [label for label in labels if paper_bandit(rep[label])]
    grid = [label for label in paper if rep[label].kind == "ultho"]
    relays = [label for label in paper if rep[label].kind == "relay"]
    relayed = {label.replace("Relay-ULTHO", "ULTHO") for label in relays}
    main = ([label for label in grid if label in relayed]
            or [label for label in grid if envs <= {r.env_id for r in runs if r.label == label}] or grid)
    main += relays
    groups = [Group("", f"the paper's protocol: {', '.join(baselines + main)}", baselines + main)]
    extra = [label for label in grid if label not in main]
    if extra:
        grid_envs = tuple(sorted({r.env_id for r in runs if r.label in extra}))
        groups.append(Group("grid", "ULTHO over its (c, W) grid, one panel per c", baselines + grid, grid_envs,
                            by_c=True))
    variants = [label for label in labels if label not in baselines + paper and rep[label].kind not in HPO_METHODS]
    if variants:
        groups.append(Group("variants", "the bandit variants", baselines + variants))
    hpo = [label for label in labels if rep[label].kind in HPO_METHODS]
    if hpo:
        groups.append(Group("hpo", "the HPO baselines", baselines + hpo))
    return groups


def method_styles(runs: list[Run]) -> dict[str, Style]:
    """One colour and line style per method, the same in every figure of a benchmark: the baseline black, the
    paper's protocol's ULTHO points first (so they get the clearest colours), a Relay-ULTHO dashed in the colour
    of the ULTHO point it relays, and no two methods alike."""
    labels = method_order(runs)
    rep = representatives(runs)
    styles: dict[str, Style] = {}
    greys = iter(["black", "dimgray", "darkgray", "silver"])
    for label in labels:
        if rep[label].kind == "ppo":
            styles[label] = Style(next(greys, "gray"))
    groups = method_groups(runs)
    ordered = [label for group in groups for label in group.labels] + labels
    colours = iter(PALETTE * 3)
    for label in dict.fromkeys(ordered):
        if label in styles or rep[label].kind == "relay":
            continue
        styles[label] = Style(next(colours))
    for label in labels:
        if rep[label].kind == "relay":
            twin = styles.get(label.replace("Relay-ULTHO", "ULTHO").replace("Relay round robin", "Round robin"))
            styles[label] = Style(twin.color if twin else next(colours), "--")
    return styles


def style_legend(figure: plt.Figure, labels: list[str], styles: dict[str, Style]) -> None:
    lines = [Line2D([], [], color=styles[label].color, linestyle=styles[label].linestyle, linewidth=1.6)
             for label in labels]
    # One row when it fits the figure's width (about 11 characters an inch, a line's sample about 5), else three
    # columns.
    one_row = sum(len(label) + 5 for label in labels) < 11 * figure.get_figwidth()
    figure.legend(lines, labels, loc="outside lower center", ncol=len(lines) if one_row else 3, frameon=False)


def group_panels(runs: list[Run], group: Group, drawn) -> list[tuple[str, str, list[str]]]:
    """(title, environment, methods) of each panel of a group's figure: the environments where its methods
    other than the baseline have runs that ``drawn`` accepts; for the (c, W) grid one panel per c."""
    rep = representatives(runs)
    others = [label for label in group.labels if rep[label].kind != "ppo"] or group.labels
    baselines = [label for label in group.labels if label not in others]
    present = {(r.label, r.env_id) for r in runs if drawn(r)}
    envs = sorted({env for label, env in present if label in others}
                  & set(group.envs or {r.env_id for r in runs}))
    panels = []
    for env in envs:
        here = [label for label in others if (label, env) in present]
        base = [label for label in baselines if (label, env) in present]
        if group.by_c:
            for c in sorted({rep[label].c for label in here}):
                panels.append((f"{env}, c = {c:g}", env, base + [label for label in here if rep[label].c == c]))
        else:
            panels.append((env, env, [label for label in group.labels if label in base + here]))
    return panels


def figure_name(kind: str, benchmark: str, group: Group) -> str:
    return f"{kind}_{benchmark}{'_' + group.key if group.key else ''}.png"


# ---------------------------------------------------------------------- learning curves and runs solved
def learning_curves(runs: list[Run], benchmark: str, styles: dict[str, Style], group: Group,
                    out: str) -> str | None:
    panels = group_panels(runs, group, lambda r: r.curve is not None)
    if not panels:
        return None
    rep = representatives(runs)
    figure, axes = env_panels(len(panels))
    shown: set[str] = set()
    for panel, (title, env_id, labels) in zip(axes, panels):
        bands = len(labels) <= BAND_LINES
        for label in labels:
            grid = on_common_grid([r.curve for r in runs if r.env_id == env_id and r.label == label])
            if grid is None:
                continue
            steps, values = grid
            mean, std = values[..., 0].mean(0), values[..., 0].std(0)
            style = styles[label]
            panel.plot(steps, mean, color=style.color, linestyle=style.linestyle, linewidth=1.3, label=label,
                       marker="o" if len(steps) == 1 else None, zorder=3 if rep[label].kind == "ppo" else 2)
            if bands or rep[label].kind == "ppo":
                panel.fill_between(steps, mean - std, mean + std, color=style.color, alpha=0.12, linewidth=0)
            shown.add(label)
        panel.set_title(title, fontsize=10)
        panel.set_ylabel("episodic return")
        steps_axis(panel)
        panel.grid(alpha=0.3)
    style_legend(figure, [label for label in group.labels if label in shown], styles)
    figure.suptitle(f"{BENCHMARKS[benchmark]}: training return, mean over seeds; band ± one std "
                    f"({'every line' if all(len(p[2]) <= BAND_LINES for p in panels) else 'the baseline only'})"
                    + ("" if group.what == "every method" else f"\n{group.what}"), fontsize=11)
    return save(figure, out, figure_name("curves", benchmark, group))


def efficiency_figure(runs: list[Run], benchmark: str, styles: dict[str, Style], group: Group, threshold: float,
                      window: int, out: str) -> str | None:
    """Per environment, the share of each method's runs whose running score has reached the threshold by step t."""
    panels = group_panels(runs, group, lambda r: r.curve is not None and reference_of(benchmark, r.env_id))
    if not panels:
        return None
    figure, axes = env_panels(len(panels))
    shown: set[str] = set()
    for panel, (title, env_id, labels) in zip(axes, panels):
        same: dict[tuple, list[str]] = {}  # methods whose runs-solved curves are identical, which hide each other
        for label in labels:
            members = [r for r in runs if r.env_id == env_id and r.label == label and r.curve is not None]
            if not members:
                continue
            found = efficiency_of(members, threshold, window)
            horizon = max(found.budgets)
            reached = sorted(s for s in found.steps if s is not None)
            steps = [0.0, *reached, float(horizon)]
            shares = [0.0, *(np.arange(1, len(reached) + 1) / len(members)), len(reached) / len(members)]
            style = styles[label]
            panel.step(steps, 100 * np.array(shares), where="post", color=style.color, linestyle=style.linestyle,
                       linewidth=1.5, label=label)
            shown.add(label)
            same.setdefault((tuple(steps), tuple(np.round(shares, 9))), []).append(label)
        # A label is not broken across lines: non-breaking spaces inside it.
        hidden = [" = ".join(label.replace(" ", "\u00a0") for label in group) for group in same.values()
                  if len(group) > 1]
        panel.set_title(title + ("\n" + textwrap.fill("identical, drawn over each other: " + "; ".join(hidden), 46)
                                 if hidden else ""), fontsize=10 if not hidden else 8.5)
        panel.set_ylabel("runs solved (%)")
        panel.set_ylim(-3, 103)
        steps_axis(panel)
        panel.grid(alpha=0.3)
    style_legend(figure, [label for label in group.labels if label in shown], styles)
    figure.suptitle(f"{BENCHMARKS[benchmark]}: runs solved (running score ≥ {threshold:g})"
                    + ("" if group.what == "every method" else f"\n{group.what}"), fontsize=11)
    return save(figure, out, figure_name("efficiency", benchmark, group))


# ---------------------------------------------------------------------- decision process and bounds
def share_panel(axes: plt.Axes, runs: list[Run]) -> bool:
    """Each cluster's cumulative share of the selections so far, mean over the runs."""
    grid = on_common_grid([cumulative_shares(r) for r in runs])
    if grid is None:
        return False
    steps, shares = grid
    axes.stackplot(steps, (100 * shares.mean(0)).T, labels=list(runs[0].search_space),
                   colors=[f"C{k}" for k in range(shares.shape[-1])], alpha=0.85)
    axes.set_ylim(0, 100)
    axes.set_xlim(steps[0], steps[-1])
    steps_axis(axes)
    return True


STRIP_CHUNKS = 200  # about the strip's width in pixels: finer detail would alias into one colour


def value_strip_panel(axes: plt.Axes, runs: list[Run]) -> bool:
    """For a search space of one cluster: one strip per run (by seed), coloured by the value it chose at each
    iteration, so that a run settling on one value, switching or rotating shows as itself (a mean over runs that
    settled on different values would show a mixture none of them ran). A run of more iterations than the strip
    has pixels is drawn in chunks, each stacked by the share of its iterations on each value: drawn one iteration
    a bar, a rotation would alias into whichever colour came last. A chunk holds a multiple of the values' count,
    so that a strict rotation shows as even bands."""
    count = len(next(iter(runs[0].search_space.values())))
    colours = strip_colours(count)
    drawn = False
    ordered = sorted(runs, key=lambda r: r.seed)
    for row, run in enumerate(ordered):
        chosen = selections(run)
        if chosen is None or not len(chosen):
            continue
        steps, picked = chosen[:, 0], chosen[:, 2].astype(int)
        # A choice holds until the next one; the last for one more iteration's steps.
        edges = np.append(steps, steps[-1] + (steps[-1] - steps[-2] if len(steps) > 1 else 1))
        size = 1 if len(picked) <= STRIP_CHUNKS else count * -(-len(picked) // (STRIP_CHUNKS * count))
        bounds = np.append(np.arange(0, len(picked), size), len(picked))  # chunk k: bounds[k] to bounds[k + 1]
        shares = np.stack([np.bincount(picked[a:b], minlength=count) / (b - a) for a, b in zip(bounds, bounds[1:])])
        starts = [k for k in range(len(shares)) if k == 0 or not np.array_equal(shares[k], shares[k - 1])]
        for k, next_k in zip(starts, [*starts[1:], len(shares)]):
            left, right = edges[bounds[k]], edges[bounds[next_k]]
            top = row - 0.4
            for value in np.flatnonzero(shares[k]):
                axes.broken_barh([(left, right - left)], (top, 0.8 * shares[k][value]), color=colours[value],
                                 linewidth=0)
                top += 0.8 * shares[k][value]
        drawn = True
    axes.set_yticks(range(len(ordered)), [f"seed {r.seed}" for r in ordered], fontsize=8)
    axes.set_ylim(len(ordered) - 0.5, -0.5)
    steps_axis(axes)
    return drawn


def strip_colours(count: int) -> np.ndarray:
    return plt.get_cmap("viridis")(np.linspace(0.15, 0.85, count))


def value_strip_handles(space: dict) -> list[Patch]:
    """The legend of value_strip_panel's colours."""
    (cluster, values), = space.items()
    return [Patch(color=colour, label=f"{cluster} = {compact(value)} (strips)")
            for value, colour in zip(values, strip_colours(len(values)))]


def value_panel(axes: plt.Axes, space: dict, shares: np.ndarray, fixed: dict | None = None,
                baseline: str = "PPO", notes: list[str] | None = None) -> None:
    """One bar per value of each cluster, ``shares`` (clusters, values) in percent; with ``fixed``, the baseline's
    own value of each cluster is hatched, edged in black and its tick label bold, and a cluster whose baseline
    value lies outside the space names it."""
    position, ticks, names, marked = 0, [], [], []
    for k, (cluster, values) in enumerate(space.items()):
        xs = position + np.arange(len(values))
        bars = axes.bar(xs, shares[k, :len(values)], color=f"C{k}", alpha=0.85)
        axes.bar_label(bars, fmt="%.0f", fontsize=7)
        own = None if fixed is None else fixed.get(cluster)
        inside = False
        for bar, value in zip(bars, values):
            if own is not None and np.isclose(float(value), float(own), rtol=1e-6):
                bar.set(edgecolor="black", linewidth=1.4, hatch="///")
                marked.append(len(ticks) + list(values).index(value))
                inside = True
        name = cluster if own is None or inside else f"{cluster}\n({baseline}: {compact(own)})"
        name += f"\n{notes[k]}" if notes else ""
        axes.text(xs.mean(), -0.2, name, transform=axes.get_xaxis_transform(), ha="center", va="top", fontsize=8,
                  color=f"C{k}")
        ticks += list(xs)
        names += [compact(v) for v in values]
        position += len(values) + 1
    axes.set_xticks(ticks, names, fontsize=7.5)
    for index in marked:
        axes.get_xticklabels()[index].set_fontweight("bold")
    axes.set_xlim(-0.7, position - 1.3)
    axes.set_ylim(0, 115)
    axes.set_yticks([0, 25, 50, 75, 100])


def decision_figures(runs: list[Run], title: str, out: str, name: str, fixed: dict | None = None,
                     baseline: str = "PPO") -> list[tuple[str, str]]:
    """The decision-process figure, one row per environment (which cluster is chosen over training, or with one
    cluster which value each run chose; each value's share of its cluster's selections; each value's share of the
    iterations it was in force, the baseline's own value marked), and the confidence bounds, one panel per
    environment: [(what, file name)] of those drawn."""
    drawn = []
    envs = sorted({r.env_id for r in runs})
    by_env = [[r for r in runs if r.env_id == env] for env in envs]
    space = runs[0].search_space
    single_cluster = len(space) == 1
    slots = sum(len(v) for v in space.values()) + len(space) - 1
    bar_width = max(3.2, 0.44 * slots)
    figure = plt.figure(figsize=(4.6 + 2 * bar_width + 0.6, 2.75 * len(envs) + 1.3), layout="constrained")
    rows = figure.subfigures(len(envs), 1, squeeze=False)[:, 0]
    any_drawn = False
    for row, env, members in zip(rows, envs, by_env):
        row.suptitle(f"{env} ({len(members)} run{'s' * (len(members) > 1)})", fontsize=10, fontweight="bold")
        shares_axes, chosen_axes, held_axes = row.subplots(1, 3, width_ratios=[4.6, bar_width, bar_width])
        if single_cluster:
            any_drawn |= value_strip_panel(shares_axes, members)
        else:
            any_drawn |= share_panel(shares_axes, members)
            shares_axes.set_ylabel("% of selections")
        counts = value_counts(members)
        totals = counts.sum(1, keepdims=True)
        value_panel(chosen_axes, space, 100 * counts / np.where(totals > 0, totals, 1), fixed, baseline,
                    [f"{int(n):,} chosen" if n else "never chosen" for n in totals[:, 0]])
        held = in_force(members)
        if held is None:
            held_axes.set_axis_off()
            held_axes.text(0.5, 0.5, "no hparams/* series logged", ha="center", va="center", color="gray",
                           transform=held_axes.transAxes)
        else:
            held_counts, held_totals = held
            value_panel(held_axes, space, 100 * held_counts / np.maximum(held_totals, 1)[:, None], fixed, baseline)
        chosen_axes.set_ylabel("% of its cluster's selections")
        if held is not None:
            held_axes.set_ylabel("% of iterations in force")
        if env == envs[0]:
            shares_axes.set_title("which value each run chose, over training" if single_cluster
                                  else "which cluster is chosen (cumulative)", fontsize=9)
            chosen_axes.set_title("which value is chosen", fontsize=9)
            held_axes.set_title("which value is in force", fontsize=9)
    handles = [Patch(color=f"C{k}", alpha=0.85, label=cluster) for k, cluster in enumerate(space)]
    if single_cluster:
        handles = value_strip_handles(space) + handles
    if fixed is not None:
        handles.append(Patch(facecolor="white", edgecolor="black", hatch="///",
                             label=f"{baseline}'s own setting (its fixed-settings runs'; value in bold)"))
    figure.legend(handles=handles, loc="outside lower center", ncol=len(handles), frameon=False, fontsize=9)
    figure.suptitle(f"{title}: decision process per environment", fontsize=12)
    if any_drawn:
        drawn.append(("decision process", save(figure, out, f"decision_{name}.png")))
    else:
        plt.close(figure)
    figure = bounds_figure(runs, title)
    if figure is not None:
        drawn.append(("confidence bounds", save(figure, out, f"bounds_{name}.png")))
    plt.close("all")
    return drawn


def coinciding(lines: list[np.ndarray], tolerance: float) -> list[list[int]]:
    """Groups of the lines' indices that lie within ``tolerance`` of the group's first line everywhere."""
    groups: list[list[int]] = []
    for k, line in enumerate(lines):
        for group in groups:
            if np.max(np.abs(lines[group[0]] - line)) <= tolerance:
                group.append(k)
                break
        else:
            groups.append([k])
    return groups


def bound_panel(axes: plt.Axes, runs: list[Run]) -> tuple[set[str], list[str]] | None:
    """Each cluster's utility U (solid) and bound (dashed), mean over the runs; lines that coincide are drawn once,
    in grey. Returns (the clusters drawn in their own colour, the clusters whose lines coincide: "a, b: U and
    U + bonus"), or None with nothing to draw."""
    grid = on_common_grid([bounds(r) for r in runs])
    if grid is None:
        return None
    steps, values = grid
    mean = values.mean(0)
    clusters = list(runs[0].search_space)
    tolerance = 1e-3 * (np.ptp(mean) or 1.0)
    coloured: set[str] = set()
    merged: dict[tuple[str, ...], list[str]] = {}
    for offset, linestyle, what in ((0, "-", "U"), (1, "--", "U + bonus")):
        lines = [mean[:, 2 * k + offset] for k in range(len(clusters))]
        for group in coinciding(lines, tolerance):
            colour = f"C{group[0]}" if len(group) == 1 else "gray"
            axes.plot(steps, lines[group[0]], color=colour, linestyle=linestyle, linewidth=1.4)
            if len(group) > 1:
                merged.setdefault(tuple(clusters[k] for k in group), []).append(what)
            else:
                coloured.add(clusters[group[0]])
    axes.set_ylabel("utility (critic value units)")
    steps_axis(axes)
    axes.grid(alpha=0.3)
    return coloured, [f"{', '.join(names)}: {' and '.join(whats)}" for names, whats in merged.items()]


def bound_handles(clusters: list[str], coloured: set[str], grey: bool) -> list[Line2D]:
    handles = [Line2D([], [], color=f"C{k}", label=cluster) for k, cluster in enumerate(clusters)
               if cluster in coloured]
    handles += [Line2D([], [], color="black", label="utility U (mean of its last W credits)"),
                Line2D([], [], color="black", linestyle="--", label="bound U + c·sqrt(ln i / N)")]
    if grey:
        handles.append(Line2D([], [], color="gray", label="clusters whose lines coincide (named above the panel)"))
    return handles


def bounds_figure(runs: list[Run], title: str) -> plt.Figure | None:
    """One panel per environment: the bounds are in its critic's units, which differ between environments."""
    envs = sorted({r.env_id for r in runs})
    figure, panels = env_panels(len(envs), width=4.4, height=3.4)
    coloured: set[str] = set()
    drawn, grey = False, False
    for panel, env in zip(panels, envs):
        members = [r for r in runs if r.env_id == env]
        found = bound_panel(panel, members)
        if found is None:
            panel.set_visible(False)
            continue
        coloured |= found[0]
        drawn, grey = True, grey or bool(found[1])
        text = f"{env} ({len(members)} run{'s' * (len(members) > 1)})"
        if found[1]:
            text += "\n" + textwrap.fill("coincide (grey): " + "; ".join(found[1]), 60)
        panel.set_title(text, fontsize=9)
    if not drawn:
        plt.close(figure)
        return None
    handles = bound_handles(list(runs[0].search_space), coloured, grey)
    figure.legend(handles=handles, loc="outside lower center", ncol=min(4, len(handles)), frameon=False, fontsize=8)
    figure.suptitle(f"{title}\neach cluster's utility and upper confidence bound, mean over runs", fontsize=11)
    return figure


def per_run_figure(run: Run, name: str, out: str) -> str | None:
    figure, ax = plt.subplots(1, 3, figsize=(16, 4.6), layout="constrained")
    drawn = share_panel(ax[0], [run])
    ax[0].set_ylabel("cumulative share of selections (%)")
    counts = value_counts([run])
    totals = counts.sum(1, keepdims=True)
    value_panel(ax[1], run.search_space, 100 * counts / np.where(totals > 0, totals, 1))
    ax[1].set_ylabel("share within its cluster (%)")
    found = bound_panel(ax[2], [run])
    if found is not None:
        ax[2].legend(handles=bound_handles(list(run.search_space), *found[:1], bool(found[1])), fontsize=7,
                     loc="upper center", bbox_to_anchor=(0.5, -0.2), ncol=2, frameon=False)
        if found[1]:
            ax[2].set_title(textwrap.fill("coincide (grey): " + "; ".join(found[1]), 70), fontsize=8)
    drawn = found is not None and drawn
    figure.legend(handles=[Patch(color=f"C{k}", label=c) for k, c in enumerate(run.search_space)],
                  loc="outside lower left", ncol=len(run.search_space), frameon=False, fontsize=8)
    figure.suptitle(f"{os.path.basename(run.path)} ({run.label}, seed {run.seed})")
    if not drawn:
        plt.close(figure)
        return None
    os.makedirs(os.path.join(out, "runs"), exist_ok=True)
    return save(figure, out, os.path.join("runs", f"{slug(name)}.png"))


# ---------------------------------------------------------------------- settings schedules
def schedule_figure(runs: list[Run], benchmark: str, out: str) -> str | None:
    """One column per HPO method on its first environment, one row per cluster: the value in force in every
    study's best-trial schedule, one colour and line style per seed; beside them, one ULTHO run's value in force
    at each iteration (the paper's (c, W) = (5, 10) where it ran, else the first ULTHO method)."""
    studies = [r for r in runs if r.kind in HPO_METHODS]
    env_id = sorted(r.env_id for r in studies)[0]
    studies = [r for r in studies if r.env_id == env_id]
    clusters = sorted({name for r in studies for _, _, settings in r.study["schedule"] for name in settings})
    if not clusters:
        return None
    labels = method_order(runs)
    methods = [label for label in labels if any(r.label == label for r in studies)]
    ultho = [r for r in runs if r.kind == "ultho" and r.env_id == env_id and paper_bandit(r)
             and all(f"hparams/{c}" in r.series for c in clusters)]
    ultho.sort(key=lambda r: ((r.c, r.window) != (5.0, 10), labels.index(r.label), r.seed))
    columns = methods + ([ultho[0].label] if ultho else [])
    space = {}
    for r in studies:
        space.update({k: list(v) for k, v in (r.study.get("search_space") or {}).items()})
    seeds = sorted({r.seed for r in studies})
    figure, panels = plt.subplots(len(clusters), len(columns), figsize=(3.9 * len(columns) + 0.8,
                                                                       2.2 * len(clusters) + 1.4),
                                  squeeze=False, layout="constrained", sharex=True, sharey="row")
    for j, label in enumerate(columns):
        members = sorted((r for r in studies if r.label == label), key=lambda r: r.seed)
        for i, cluster in enumerate(clusters):
            panel = panels[i, j]
            log = cluster == "learning_rate" or cluster.endswith("_lr")
            known = space.get(cluster) or []
            spread = (max(known) - min(known)) if len(known) > 1 else 1.0
            for r in members:
                n = seeds.index(r.seed)
                shift = n - (len(seeds) - 1) / 2  # seeds apart by a hair, so equal values stay visible
                steps, values = [], []
                for start, end, settings in r.study["schedule"]:
                    value = settings[cluster]
                    steps += [start, end]
                    values += [value * (1 + 0.025 * shift) if log else value + 0.012 * spread * shift] * 2
                colour, linestyle = SEED_STYLES[n % len(SEED_STYLES)]
                panel.plot(steps, values, color=colour, linestyle=linestyle, linewidth=1.8)
            if not members:  # the ULTHO column
                series = ultho[0].series[f"hparams/{cluster}"]
                panel.scatter(series[:, 0], series[:, 1], s=6, color="dimgray", alpha=0.5, linewidths=0)
            if log:
                panel.set_yscale("log")
            if known:
                panel.yaxis.set_major_locator(FixedLocator(known))
                panel.yaxis.set_minor_locator(NullLocator())
                panel.yaxis.set_major_formatter(FuncFormatter(lambda value, _: compact(value)))
            panel.grid(alpha=0.3)
            if j == 0:
                panel.set_ylabel(cluster)
            if i == 0:
                panel.set_title(label if members else f"{label}, seed {ultho[0].seed}", fontsize=10)
        steps_axis(panels[-1, j])
    handles = [Line2D([], [], color=SEED_STYLES[n % len(SEED_STYLES)][0],
                      linestyle=SEED_STYLES[n % len(SEED_STYLES)][1], linewidth=1.8,
                      label=f"seed {seed}: the best trial's setting") for n, seed in enumerate(seeds)]
    if ultho:
        handles.append(Line2D([], [], color="dimgray", marker="o", markersize=3, linestyle="none",
                              label="ULTHO: the value in force at each iteration"))
    figure.legend(handles=handles, loc="outside lower center", ncol=len(handles), frameon=False, fontsize=9)
    figure.suptitle(f"{BENCHMARKS[benchmark]} {env_id}: settings schedules (seeds drawn a hair apart so that "
                    "equal values stay visible)", fontsize=11)
    return save(figure, out, f"schedules_{benchmark}.png")


# ---------------------------------------------------------------------- robustness over (c, W)
def robustness_figure(runs: list[Run], benchmark: str, grid: dict, seed: int, reps: int,
                      out: str) -> tuple[str | None, list[str], list[tuple[str, float, int]]]:
    """One panel per environment with ULTHO runs at two or more (c, W) points, on one shared y range: the mean
    score at each (c, W) with its 95% interval, and the fixed-settings baseline.
    Returns (file name, the (c, W) cells of the sweeps' grids without scored runs, the environments left out for
    having one point: (env, c, W))."""
    ultho = [r for r in runs if r.kind == "ultho" and r.score is not None and paper_bandit(r)]
    points_of = {env: grid.get((benchmark, env), set()) | {(r.c, r.window) for r in ultho if r.env_id == env}
                 for env in sorted({r.env_id for r in ultho})}
    single = [(env, *point) for env, points in points_of.items() if len(points) == 1 for point in points]
    envs = [env for env, points in points_of.items() if len(points) > 1]
    if not envs:
        return None, [], single
    figure, panels = env_panels(len(envs), width=5.0, height=3.6, sharey=True)
    empty = []
    for k, (panel, env_id) in enumerate(zip(panels, envs)):
        here = [r for r in ultho if r.env_id == env_id]
        points = points_of[env_id]
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
        ppo = strata_of([r for r in runs if r.label == baseline_of(benchmark) and r.env_id == env_id])
        if ppo:
            point, low, high = (100 * v for v in aggregate_with_interval(ppo, "mean", seed, reps))
            panel.axhline(point, color="black", linestyle="--", label=f"{baseline_of(benchmark)} (fixed settings)")
            panel.axhspan(low, high, color="black", alpha=0.08, zorder=0)
        panel.set_xticks(range(len(windows)), [f"W = {w}" for w in windows])
        panel.set_xlim(-0.5, len(windows) - 0.5)
        panel.set_title(env_id, fontsize=10)
        if k % 4 == 0:
            panel.set_ylabel("score (%), mean with 95% CI")
        panel.grid(axis="y", alpha=0.3)
        panel.legend(loc="lower left", fontsize=7, framealpha=0.8)
    figure.suptitle(f"{BENCHMARKS[benchmark]}: ULTHO over (c, W), the sliding window W on the x axis; "
                    "one y range for every panel", fontsize=11)
    return save(figure, out, f"robustness_{benchmark}.png"), empty, single

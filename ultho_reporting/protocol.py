"""The paper's reporting protocol, applied to both sides: the best (c, W) of a grid per environment for ULTHO, and
the same selection for fixed-settings PPO.

The paper grid-searches ULTHO's exploration coefficient c and window W and reports the best point per environment
against one fixed-settings PPO run per seed. Picking the best of K points, each a mean over m seeds, raises a
score by itself, whatever the points are: the report shows that rise on PPO, where nothing is tuned, as the
expected best mean of K groups of m PPO runs. With K x m PPO runs or more, each draw splits K x m distinct runs into
the groups (what K x m independent runs would give); with fewer, the groups are drawn with replacement from the runs
there are (a bootstrap, which narrows the spread of a few runs), and the section says which.
"""

import re
from dataclasses import dataclass

import numpy as np

from ultho_reporting.runs import Run, baseline_of

MAX_DRAWS = 20_000
"""Draws of the K groups for the PPO estimate (fewer when --reps asks for fewer)."""


@dataclass(frozen=True)
class Selection:
    """One method family's best (c, W) on one environment, and the same selection made on PPO."""

    env_id: str
    family: str  # the method without its (c, W)
    points: int  # K: the (c, W) points with scored runs
    seeds: int  # m: the seeds every point has scored runs on (the points are compared on those alone)
    best_point: tuple[float, int]
    best: float  # the best point's mean raw score
    mean_of_points: float  # the mean of the points' means
    best_score: float | None  # the best point's mean normalized score
    ppo_runs: int  # n
    ppo: float | None  # PPO's mean raw score
    ppo_best: float | None  # the expected best mean of K groups of m PPO runs, raw
    ppo_best_score: float | None  # the same, normalized

    @property
    def distinct(self) -> bool:
        """Whether the PPO groups are distinct runs (K x m runs or more) rather than a bootstrap."""
        return self.ppo_runs >= self.points * self.seeds


def family_of(label: str) -> str:
    """The method's name without its (c, W) or (W): the methods a grid over (c, W) makes are one family."""
    return re.sub(r" \((c=[^,]+, )?W=\d+\)", "", label)


def expected_best_of_groups(scores: np.ndarray, groups: int, size: int, seed: int, draws: int) -> float:
    """E[max over `groups` groups of the mean of `size` runs from `scores`]: the groups are distinct runs when
    there are ``groups * size`` or more, else drawn with replacement."""
    rng = np.random.default_rng(seed)
    if len(scores) >= groups * size:
        picks = rng.permuted(np.tile(np.arange(len(scores)), (draws, 1)), axis=1)[:, :groups * size]
        picks = picks.reshape(draws, groups, size)
    else:
        picks = rng.integers(len(scores), size=(draws, groups, size))
    return float(scores[picks].mean(axis=2).max(axis=1).mean())


def best_points(runs: list[Run], benchmark: str, seed: int, reps: int) -> list[Selection]:
    """Every (family, environment) with scored ULTHO runs at two or more (c, W) points, compared on the seeds they
    all have."""
    found = []
    baseline = baseline_of(benchmark)
    grids: dict[tuple[str, str], dict[tuple[float, int], list[Run]]] = {}
    for run in runs:
        if run.kind == "ultho" and run.c is not None and run.raw_score is not None:
            key = (family_of(run.label), run.env_id)
            grids.setdefault(key, {}).setdefault((run.c, run.window), []).append(run)
    for (family, env_id), points in sorted(grids.items(), key=lambda item: (item[0][1], item[0][0])):
        shared = set.intersection(*({r.seed for r in members} for members in points.values()))
        if len(points) < 2 or not shared:
            continue
        # Points compared on different seeds would rank the seeds as much as the points (a grid still running).
        points = {point: [r for r in members if r.seed in shared] for point, members in points.items()}
        means = {point: float(np.mean([r.raw_score for r in members])) for point, members in points.items()}
        best_point = max(sorted(means), key=means.get)
        normalized = [r.score for r in points[best_point]]
        ppo = [r for r in runs if r.label == baseline and r.env_id == env_id and r.raw_score is not None]
        size = len(shared)
        draws = min(MAX_DRAWS, reps)
        raw = np.array([r.raw_score for r in ppo])
        scored = np.array([r.score for r in ppo if r.score is not None])
        found.append(Selection(
            env_id, family, len(points), size, best_point, means[best_point], float(np.mean(list(means.values()))),
            float(np.mean(normalized)) if None not in normalized else None, len(ppo),
            float(raw.mean()) if len(raw) else None,
            expected_best_of_groups(raw, len(points), size, seed, draws) if len(raw) else None,
            expected_best_of_groups(scored, len(points), size, seed, draws) if len(scored) == len(ppo) and len(ppo)
            else None))
    return found


def number(value: float) -> str:
    """A raw score, with the third decimal that MiniGrid's scores near 1 differ in."""
    return f"{value:.3f}" if abs(value) < 10 else f"{value:,.0f}"


def protocol_section(runs: list[Run], benchmark: str, seed: int, reps: int) -> list[str]:
    """The section's lines (none without a grid over (c, W))."""
    found = best_points(runs, benchmark, seed, reps)
    if not found:
        return []
    baseline = baseline_of(benchmark)
    draws = min(MAX_DRAWS, reps)
    lines = ["### The paper's protocol: the best (c, W) per environment, on both sides", "",
             f"The paper reports each environment's best (c, W) of its grid against one fixed-settings {baseline} run "
             "per seed. Here, for each ULTHO method with scored runs at K >= 2 points (c, W) on an environment: the "
             "point with the highest mean final score over its seeds, beside the mean of all K points' means; and "
             f"the same selection made on {baseline}, where nothing is tuned: the expected best mean of K groups of "
             f"m {baseline} runs (m: the seeds every point has, on which alone the points are compared; {draws:,} "
             f"draws, seed {seed}): "
             f"K x m distinct runs split into the groups where there are that many {baseline} runs (marked "
             "distinct), else groups drawn with replacement from the runs there are (marked bootstrap, which "
             f"narrows the spread of a few runs). What the best-of-K column gains over the plain {baseline} column "
             "is the selection's own effect.", "",
             f"| environment | method | K points x m seeds | best (c, W) | its mean | mean of the K points | "
             f"{baseline} (runs) | {baseline}, best of K groups of m |",
             "|---|---|---|---|---|---|---|---|"]
    for s in found:
        c, window = s.best_point
        ppo = "–" if s.ppo is None else f"{number(s.ppo)} ({s.ppo_runs})"
        drawn = "distinct" if s.distinct else "bootstrap"
        best_of_groups = "–" if s.ppo_best is None else f"{number(s.ppo_best)} ({drawn})"
        lines.append(f"| {s.env_id} | {s.family} | {s.points} x {s.seeds} | c={c:g}, W={window} | {number(s.best)} | "
                     f"{number(s.mean_of_points)} | {ppo} | {best_of_groups} |")
    lines.append("")
    for family in sorted({s.family for s in found}):
        members = [s for s in found if s.family == family and s.best_score is not None and s.ppo_best_score is not None]
        if len(members) < 2:
            continue
        lines.append(f"Over the {len(members)} environments where {family} has a grid: its best (c, W) scores "
                     f"{100 * np.mean([s.best_score for s in members]):.1f}% on average, {baseline}'s best of K groups "
                     f"{100 * np.mean([s.ppo_best_score for s in members]):.1f}% (normalized as in the aggregate "
                     "tables).")
    return lines + [""] * (lines[-1] != "")

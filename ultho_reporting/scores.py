"""The numbers the report states about scores: aggregates over runs, sample efficiency and areas.

Aggregates follow Agarwal et al. 2021 (what ``rliable`` computes, here with numpy): the mean and the
interquartile mean of all environment x seed scores, with 95% percentile intervals from a bootstrap that
resamples the seeds independently within each environment. Sample efficiency is the environment steps until
a run's running score first reaches a threshold; the area is the mean normalized score over training. Every
score here is on its benchmark's fixed scale (``references``), set on each run by ``Study.normalize``.
"""

import itertools
from collections import defaultdict
from dataclasses import dataclass

import numpy as np

from ultho_reporting.references import reference_of
from ultho_reporting.runs import Run


def interquartile_mean(scores: np.ndarray) -> np.ndarray:
    """Mean of the middle 50% along the last axis, as scipy.stats.trim_mean(x, 0.25): int(n/4) cut at each end."""
    n = scores.shape[-1]
    cut = int(0.25 * n)
    return np.sort(scores, axis=-1)[..., cut:n - cut].mean(axis=-1)


AGGREGATES = {"mean": lambda scores: scores.mean(axis=-1), "IQM": interquartile_mean}


def aggregate_with_interval(strata: list[np.ndarray], name: str, seed: int, reps: int) -> tuple[float, float, float]:
    """(point, low, high): the aggregate of all scores and its 95% percentile interval from a stratified
    bootstrap that resamples runs with replacement independently within each game."""
    aggregate = AGGREGATES[name]
    rng = np.random.default_rng(seed)
    resampled = np.concatenate([s[rng.integers(0, len(s), size=(reps, len(s)))] for s in strata], axis=1)
    low, high = np.percentile(aggregate(resampled), [2.5, 97.5])
    return float(aggregate(np.concatenate(strata))), float(low), float(high)


def strata_of(runs: list[Run], envs: set[str] | None = None) -> list[np.ndarray]:
    """The normalized scores grouped by environment (only ``envs`` when given), in a fixed order."""
    games = defaultdict(list)
    for run in runs:
        if run.score is not None and (envs is None or run.env_id in envs):
            games[run.env_id].append(run.score)
    return [np.array(games[g]) for g in sorted(games)]


def coverage_groups(runs: list[Run], methods: list[str]) -> list[tuple[list[str], list[str]]]:
    """[(environments, methods)]: one group for each set of environments some method has scored runs on, the
    widest set first, holding every method with scored runs on all of them (in ``methods``' order). Each
    aggregate table compares its methods over exactly the same environments, so a method run on fewer
    environments (a study still going, a grid on one environment) is compared there with the others."""
    covered: dict[str, frozenset] = {}
    for label in methods:
        envs = frozenset(r.env_id for r in runs if r.label == label and r.score is not None)
        if envs:
            covered[label] = envs
    ordered = sorted(set(covered.values()), key=lambda envs: (-len(envs), sorted(envs)))
    return [(sorted(envs), [label for label in methods if label in covered and envs <= covered[label]])
            for envs in ordered]


def steps_to_threshold(curve: np.ndarray | None, benchmark: str, env_id: str, threshold: float,
                       window: int) -> float | None:
    """The first logged step at which the running score reaches ``threshold``, else None.

    The running score is the mean of the last ``window`` logged training returns (each the mean return of the
    episodes that ended in one iteration), on the benchmark's fixed scale, so a single lucky iteration does not
    count as solving the task. It starts once the window is as full as the curve allows: at the ``window``-th
    logged return, the mean of all returns so far; a curve with fewer returns than ``window`` has a running
    score only at its last step, the mean of all its returns.
    """
    reference = reference_of(benchmark, env_id)
    if curve is None or not len(curve) or reference is None:
        return None
    low, high = reference
    scores = (curve[:, 1] - low) / (high - low)
    # np.convolve swaps its arguments when the curve is the shorter one: the window never exceeds the curve.
    window = min(window, len(scores))
    running = np.convolve(scores, np.ones(window) / window, mode="valid")
    reached = np.nonzero(running >= threshold)[0]
    return float(curve[reached[0] + window - 1, 0]) if len(reached) else None


@dataclass
class Efficiency:
    """Steps to the threshold of a group of runs; runs that never reached it count with their whole budget."""

    steps: list[float]
    budgets: list[int]

    @property
    def reached(self) -> int:
        return sum(s is not None for s in self.steps)

    @property
    def censored_mean(self) -> float:
        return float(np.mean([b if s is None else s for s, b in zip(self.steps, self.budgets)]))

    def text(self) -> str:
        if not self.steps:
            return "–"
        prefix = "≥ " if self.reached < len(self.steps) else ""
        return f"{prefix}{steps_text(self.censored_mean)} ({self.reached}/{len(self.steps)})"


def steps_text(steps: float) -> str:
    """12,345 below 100k, else 123k or 1.23M: the precision a table of environment steps needs."""
    if steps < 100_000:
        return f"{steps:,.0f}"
    return f"{steps / 1e3:.0f}k" if steps < 1e6 else f"{steps / 1e6:.3g}M"


def efficiency_of(runs: list[Run], threshold: float, window: int, from_start: bool = False) -> Efficiency:
    """``from_start``: count the steps a method spent before its scored run began (a relay's full run) too."""
    scored = [r for r in runs if r.curve is not None and reference_of(r.benchmark, r.env_id) is not None]
    offsets = [r.start_offset if from_start else 0 for r in scored]
    steps = [steps_to_threshold(r.curve, r.benchmark, r.env_id, threshold, window) for r in scored]
    return Efficiency([None if s is None else s + offset for s, offset in zip(steps, offsets)],
                      [r.curve_budget + offset for r, offset in zip(scored, offsets)])


def better_of_two(runs: list[Run]) -> list[Run]:
    """Fixed-settings PPO selected as a relay is: for every pair of seeds on an environment, the run with the
    higher final score (the lower seed on a tie, as a relay prefers its COI run)."""
    winners = []
    for env_id in sorted({r.env_id for r in runs}):
        scored = sorted((r for r in runs if r.env_id == env_id and r.raw_score is not None), key=lambda r: r.seed)
        winners += [a if a.raw_score >= b.raw_score else b for a, b in itertools.combinations(scored, 2)]
    return winners


def normalized_area(run: Run) -> float | None:
    """The area under the run's normalized learning curve divided by its length: the mean score over training
    (trapezoids between the logged returns, from the first logged step to the last)."""
    reference = reference_of(run.benchmark, run.env_id)
    if run.curve is None or len(run.curve) < 2 or reference is None:
        return None
    low, high = reference
    steps, scores = run.curve[:, 0], (run.curve[:, 1] - low) / (high - low)
    return float(np.sum((scores[1:] + scores[:-1]) / 2 * np.diff(steps)) / (steps[-1] - steps[0]))

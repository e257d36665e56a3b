"""The bandit's decisions read back from a ULTHO run's logged series.

Each ULTHO run logs, per iteration, the cluster and value it selected (``ultho/selected_*``), and for UCB each
cluster's utility, bound and bonus (``ultho/<kind>/<cluster>``); ``summary.json`` adds the credited selections
of every value. From these: which cluster and value were chosen over training, the bounds the choice
maximised, and how far the choices followed the bonus rather than the utilities.
"""

import numpy as np

from ultho_reporting.runs import Run


def selections(run: Run) -> np.ndarray | None:
    """(T, 3): step, cluster index, value index of every selection of the run."""
    cluster, value = run.series.get("ultho/selected_cluster"), run.series.get("ultho/selected_value_index")
    if cluster is None or value is None or len(cluster) != len(value):
        return None
    chosen = np.column_stack([cluster, value[:, 1]])
    return chosen[chosen[:, 1] >= 0]


def cumulative_shares(run: Run) -> np.ndarray | None:
    """(T, 1 + K): step and each cluster's share among the selections so far."""
    chosen = selections(run)
    if chosen is None or not len(chosen):
        return None
    onehot = chosen[:, 1:2] == np.arange(len(run.search_space))
    return np.column_stack([chosen[:, 0], onehot.cumsum(0) / np.arange(1, len(chosen) + 1)[:, None]])


def aligned_series(run: Run, tags: list[str]) -> np.ndarray | None:
    """(T, 1 + len(tags)): step, then each tag's value; None unless the run logged every tag equally often."""
    if not tags or not all(tag in run.series for tag in tags) or len({len(run.series[t]) for t in tags}) != 1:
        return None
    return np.column_stack([run.series[tags[0]][:, 0]] + [run.series[t][:, 1] for t in tags])


def bounds(run: Run) -> np.ndarray | None:
    """(T, 1 + 2K): step, then each cluster's utility and upper confidence bound."""
    return aligned_series(run, [f"ultho/{kind}/{cluster}" for cluster in run.search_space
                                for kind in ("utility", "ucb")])


def value_counts(runs: list[Run]) -> np.ndarray:
    """(clusters, most values): how often each value was selected, pooled over the runs."""
    space = runs[0].search_space
    counts = np.zeros((len(space), max(len(v) for v in space.values())))
    for chosen in filter(lambda c: c is not None, map(selections, runs)):
        for _, cluster, value in chosen:
            counts[int(cluster), int(value)] += 1
    return counts


def exploration_ratio(run: Run) -> float | None:
    """How far UCB's choices were the bonus's rather than the utilities': over the second half of the run, the
    median of the clusters' mean bonus c·sqrt(ln i / N) divided by the spread (max - min) of their utilities in
    the units the bound adds them in. Above 1 the bonus outweighs what separates the clusters (they are taken
    in turn); well below 1 the bandit follows the utilities. None for other strategies or without the series."""
    series = aligned_series(run, [f"ultho/{kind}/{cluster}" for cluster in run.search_space or {}
                                  for kind in ("ucb", "bonus")])
    if series is None:
        return None
    ucb, bonus = series[:, 1::2], series[:, 2::2]
    half = slice(len(ucb) // 2, None)
    scaled_utility = (ucb - bonus)[half]
    spread = scaled_utility.max(1) - scaled_utility.min(1)
    ratio = bonus[half].mean(1) / np.where(spread > 0, spread, np.nan)
    return float(np.nanmedian(ratio)) if np.isfinite(ratio).any() else None


def in_force(runs: list[Run]) -> tuple[np.ndarray, np.ndarray] | None:
    """How long each value was in force, pooled over the runs: ((clusters, most values) logged iterations at each
    value of the search space, (clusters,) logged iterations in all), from the ``hparams/<cluster>`` series; a
    cluster the bandit stopped choosing keeps its last value, and one it never chose the script's setting (which
    may lie outside the space). None when no run logged them."""
    space = runs[0].search_space
    counts = np.zeros((len(space), max(len(v) for v in space.values())))
    totals = np.zeros(len(space))
    logged = False
    for run in runs:
        for k, (cluster, values) in enumerate(space.items()):
            series = run.series.get(f"hparams/{cluster}")
            if series is None or not len(series):
                continue
            logged = True
            totals[k] += len(series)
            for j, value in enumerate(values):
                # TensorBoard keeps float32: 0.0025 comes back as 0.0024999999.
                counts[k, j] += np.isclose(series[:, 1], float(value), rtol=1e-5, atol=0).sum()
    return (counts, totals) if logged else None

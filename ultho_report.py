"""The paper's figures and tables from ULTHO run directories, in one command.

Reads every run directory below the given paths (TensorBoard events through tensorboard's own reader,
``summary.json``, Relay-ULTHO's ``relay.json`` and ``sweep.py``'s ``sweep.json``), groups the runs by
benchmark, environment and method (PPO, ULTHO per (c, W), Relay-ULTHO) and writes PNG figures plus one
``report.md`` that shows them with the tables:

1. learning curves per environment (mean and standard deviation over seeds, one line per method);
2. the aggregate table: normalized score per method, mean and IQM with 95% stratified-bootstrap intervals
   over seeds and games (Agarwal et al. 2021), and the budget in steps; also ``aggregate.csv``;
3. the decision process: cumulative share of each cluster among the selections, share of each value
   within its cluster, aggregated over runs and per run;
4. each cluster's utility and upper confidence bound over training;
5. robustness: the aggregate score over the (c, W) grid.

    python ultho_report.py runs/ --out report/
"""

import argparse
import csv
import json
import logging
import os
import re
import sys
from collections import Counter, defaultdict
from dataclasses import dataclass, field

import matplotlib

matplotlib.use("Agg")  # headless: figures go to files only
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.ticker import EngFormatter  # noqa: E402
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator  # noqa: E402

PROG = "ultho_report"

PROCGEN_EASY = {
    "bigfish": (1, 40), "bossfight": (0.5, 13), "caveflyer": (3.5, 12), "chaser": (0.5, 13),
    "climber": (2, 12.6), "coinrun": (5, 10), "dodgeball": (1.5, 19), "fruitbot": (-1.5, 32.4),
    "heist": (3.5, 10), "jumper": (3, 10), "leaper": (3, 10), "maze": (5, 10), "miner": (1.5, 13),
    "ninja": (3.5, 10), "plunder": (4.5, 30), "starpilot": (2.5, 64),
}
"""Procgen easy-mode (R_min, R_max), Cobbe et al. 2020 (ULTHO_SPEC.md)."""

ALE_HUMAN = {
    "BattleZone": (2360.0, 37187.5), "DoubleDunk": (-18.6, -16.4), "NameThisGame": (2292.3, 8049.0),
    "Phoenix": (761.4, 7242.6), "Qbert": (163.9, 13455.0),
}
"""ALE (random, human) scores for human normalization (ULTHO_SPEC.md)."""

BENCHMARKS = {"procgen": "Procgen", "atari": "ALE", "minigrid": "MiniGrid", "pybullet": "PyBullet"}
NORMALIZATION = {
    "procgen": "Procgen easy-mode min-max normalized test score (Cobbe et al. 2020 constants)",
    "atari": "human-normalized score, (R - random) / (human - random)",
}
MIN_MAX_OVER_RUNS = "min-max normalized final score per environment over the runs present (0 = the worst run, 1 = the best)"
RETURN_TAG = "charts/episodic_return"
GRID_POINTS = 200
STEPS = EngFormatter(sep="")


class DamagedEventFiles(logging.Handler):
    """tensorboard's reader reports a truncated or corrupt record only as a debug log line; collect them."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.files: set[str] = set()

    def emit(self, record: logging.LogRecord) -> None:
        if str(record.msg).startswith("Truncated record in"):
            self.files.add(str(record.args[0]))


damaged = DamagedEventFiles()


@dataclass
class Run:
    """One scored entry of the report: a training run, or a whole relay (scored by its winner)."""

    path: str
    benchmark: str
    env_id: str
    kind: str  # "ppo", "ultho" or "relay"
    c: float | None
    window: int | None
    seed: int
    budget: int
    raw_score: float | None
    score_note: str | None = None
    curve: np.ndarray | None = None  # (T, 2): step, episodic return
    series: dict[str, np.ndarray] = field(default_factory=dict)  # ultho/* tags -> (T, 2)
    search_space: dict[str, list] | None = None
    score: float | None = None  # normalized, set by Study.normalize
    label: str = ""  # the method, set by Study.label_methods
    narrowed: bool = False  # ULTHO on a search space other than its benchmark's widest (set with the label)


class Study:
    """Everything found below the given paths, and what was missing or unreadable."""

    def __init__(self) -> None:
        self.runs: list[Run] = []
        self.warnings: list[str] = []
        self.missing: list[str] = []
        self.grid: dict[str, tuple[set, set]] = defaultdict(lambda: (set(), set()))  # benchmark -> (c, W)
        self._seen: set[str] = set()

    def warn(self, path: str, what: str) -> None:
        line = f"{path}: {what}"
        if line not in self.warnings:
            self.warnings.append(line)
            print(f"{PROG}: warning: {line}", file=sys.stderr)

    def read_json(self, path: str) -> dict | None:
        try:
            with open(path) as f:
                data = json.load(f)
        except FileNotFoundError:
            self.warn(path, "missing; skipped")
            return None
        except (OSError, ValueError) as err:
            self.warn(path, f"unreadable ({err.__class__.__name__}: {err}); skipped")
            return None
        if not isinstance(data, dict):
            self.warn(path, "not a JSON object; skipped")
            return None
        return data

    def read_scalars(self, run_dir: str) -> dict[str, np.ndarray]:
        """The return curve and the ultho/* series, read with tensorboard's own reader."""
        if not any(name.startswith("events.out.tfevents") for name in os.listdir(run_dir)):
            self.warn(run_dir, "no TensorBoard event files; no curves for this run")
            return {}
        damaged.files.clear()
        accumulator = EventAccumulator(run_dir, size_guidance={"scalars": 0})
        try:
            accumulator.Reload()
            tags = accumulator.Tags()["scalars"]
            series = {tag: np.array([(e.step, e.value) for e in accumulator.Scalars(tag)], dtype=float)
                      for tag in tags if tag == RETURN_TAG or tag.startswith("ultho/")}
        except Exception as err:  # noqa: BLE001  (a damaged file of any kind is skipped, never a traceback)
            self.warn(run_dir, f"TensorBoard events unreadable ({err.__class__.__name__}); no curves for this run")
            return {}
        for event_file in sorted(damaged.files):
            self.warn(event_file, "damaged or truncated TensorBoard events; read up to the damage")
        return series

    # ------------------------------------------------------------------ discovery
    def discover(self, roots: list[str]) -> None:
        sweeps, relays, run_dirs = [], [], []
        for root in roots:
            for directory, subdirs, files in os.walk(root):
                subdirs.sort()
                if "sweep.json" in files:
                    sweeps.append(directory)
                if "relay.json" in files:
                    relays.append(directory)
                elif "summary.json" in files or any(f.startswith("events.out.tfevents") for f in files):
                    run_dirs.append(directory)
        for directory in sweeps:
            listed_relays, listed_runs = self.load_sweep(directory)
            relays += listed_relays
            run_dirs += listed_runs
        relay_dirs = [os.path.realpath(d) + os.sep for d in relays]
        for directory in relays:
            self.load_relay(directory)
        for directory in run_dirs:
            # A run inside a relay directory is one of the relay's own runs, scored with the relay.
            if not any(os.path.realpath(directory).startswith(relay) for relay in relay_dirs):
                self.load_run(directory)

    def claim(self, path: str) -> bool:
        """False when this directory was already read (given twice, or both found and listed in a sweep)."""
        real = os.path.realpath(path)
        if real in self._seen:
            return False
        self._seen.add(real)
        return True

    def load_sweep(self, directory: str) -> tuple[list[str], list[str]]:
        path = os.path.join(directory, "sweep.json")
        sweep = self.read_json(path)
        relays, runs = [], []
        if sweep is None:
            return relays, runs
        try:
            grid = sweep["grid"]
            for script in grid["scripts"]:
                cs, windows = self.grid[benchmark_of(script)]
                if "ultho" in grid["methods"] or "relay" in grid["methods"]:
                    cs.update(float(c) for c in grid["c"])
                    windows.update(int(w) for w in grid["window"])
            for entry in sweep["runs"]:
                where = os.path.join(directory, entry["path"])
                if entry["status"] != "done":
                    error = f": {entry['error']}" if entry.get("error") else ""
                    self.missing.append(f"sweep run `{entry['name']}` ({entry['method']}, {entry['env_id']}, seed "
                                        f"{entry['seed']}) is {entry['status']}{error}")
                elif not os.path.isdir(where):
                    self.warn(where, "listed as done in sweep.json but not there; skipped")
                else:
                    (relays if entry["method"] == "relay" else runs).append(where)
        except (KeyError, TypeError, ValueError) as err:
            self.warn(path, f"not in the sweep.json format ({err.__class__.__name__}: {err}); its index is skipped")
        return relays, runs

    def load_relay(self, directory: str) -> None:
        path = os.path.join(directory, "relay.json")
        if not self.claim(directory) or (relay := self.read_json(path)) is None:
            return
        try:
            if relay["status"] != "done":
                self.missing.append(f"relay `{directory}` ({relay['env_id']}, seed {relay['seed']}) is still running")
                return
            winner_dir = os.path.join(directory, relay["winner_run"])
            full_dir = os.path.join(directory, relay["full_run"])
            benchmark, seed, budget = benchmark_of(relay["script"]), int(relay["seed"]), int(relay["total_timesteps"])
            env_id = str(relay["env_id"])
        except (KeyError, TypeError, ValueError) as err:
            self.warn(path, f"not in the relay.json format ({err.__class__.__name__}: {err}); skipped")
            return
        winner = self.read_summary(winner_dir)
        if winner is None:
            return
        full = self.read_summary(full_dir) or {}
        full_bandit = full.get("bandit") or {}
        run = Run(directory, benchmark, env_id, "relay", full_bandit.get("c"), full_bandit.get("window"), seed,
                  budget, *raw_score(winner, benchmark), curve=self.read_scalars(winner_dir).get(RETURN_TAG))
        self.runs.append(run)

    def read_summary(self, run_dir: str) -> dict | None:
        """summary.json with the fields the report needs checked; None (and a warning) when unusable."""
        path = os.path.join(run_dir, "summary.json")
        summary = self.read_json(path)
        if summary is None:
            return None
        try:
            str(summary["env_id"]), int(summary["seed"]), int(summary["global_step"])
            if summary["ultho"]:
                bandit = summary["bandit"]
                float(bandit["c"]), int(bandit["window"]), dict(bandit["search_space"])
            raw_score(summary, benchmark_of(summary["script"]))
        except (KeyError, TypeError, ValueError) as err:
            self.warn(path, f"not in the summary.json format ({err.__class__.__name__}: {err}); skipped")
            return None
        return summary

    def load_run(self, run_dir: str) -> None:
        if not self.claim(run_dir):
            return
        if not os.path.exists(os.path.join(run_dir, "summary.json")):
            self.warn(run_dir, "no summary.json (a run still going, or one that crashed); skipped")
            return
        summary = self.read_summary(run_dir)
        if summary is None:
            return
        benchmark = benchmark_of(summary["script"])
        bandit = summary["bandit"] if summary["ultho"] else None
        scalars = self.read_scalars(run_dir)
        self.runs.append(Run(
            run_dir, benchmark, summary["env_id"], "ultho" if bandit else "ppo",
            float(bandit["c"]) if bandit else None, int(bandit["window"]) if bandit else None,
            int(summary["seed"]), int(summary["global_step"]), *raw_score(summary, benchmark),
            curve=scalars.get(RETURN_TAG), series={k: v for k, v in scalars.items() if k.startswith("ultho/")},
            search_space=bandit["search_space"] if bandit else None,
        ))

    # ------------------------------------------------------------------ scores and methods
    def normalize(self) -> None:
        by_env = defaultdict(list)
        for run in self.runs:
            if run.raw_score is None:
                self.missing.append(f"`{run.path}` has no score (no training episode ended)")
            elif run.benchmark in NORMALIZATION:
                run.score = fixed_normalization(run.benchmark, run.env_id, run.raw_score)
                if run.score is None:
                    self.missing.append(f"`{run.path}`: no normalization constants for {run.env_id}; not scored")
            else:
                by_env[(run.benchmark, run.env_id)].append(run)
        for (_, env_id), runs in by_env.items():
            low, high = min(r.raw_score for r in runs), max(r.raw_score for r in runs)
            if high > low:
                for run in runs:
                    run.score = (run.raw_score - low) / (high - low)
            else:
                self.missing.append(f"{env_id}: every run scored {low:g}, so min-max normalization has no range; "
                                    "not scored")

    def label_methods(self) -> None:
        """PPO, ULTHO (c, W), Relay-ULTHO (c, W); a search space other than the benchmark's widest one is named."""
        widest = {}
        for run in self.runs:
            if run.search_space and len(run.search_space) > len(widest.get(run.benchmark, {})):
                widest[run.benchmark] = run.search_space
        for run in self.runs:
            if run.kind == "ppo":
                run.label = "PPO"
                continue
            setting = f" (c={run.c:g}, W={run.window})" if run.c is not None else ""
            run.label = ("ULTHO" if run.kind == "ultho" else "Relay-ULTHO") + setting
            run.narrowed = bool(run.search_space) and run.search_space != widest[run.benchmark]
            if run.narrowed:
                run.label += " on " + ", ".join(f"{k}={'/'.join(map(str, v))}" for k, v in run.search_space.items())


def benchmark_of(script: str) -> str:
    """The benchmark of a script name, with or without ".py" (summary.json leaves it out, the indexes keep it)."""
    match = re.fullmatch(r"ppo_ultho_(\w+?)(?:\.py)?", os.path.basename(str(script)))
    if not match or match.group(1) not in BENCHMARKS:
        raise ValueError(f"unknown script {script!r}")
    return match.group(1)


def raw_score(summary: dict, benchmark: str) -> tuple[float | None, str | None]:
    """(score before normalization, note): Procgen's test score, else the final training score."""
    if benchmark == "procgen":
        if summary.get("test_score") is not None:
            return float(summary["test_score"]), None
        note = "training score used: no test_score"
    else:
        note = None
    return (None if summary["final_score"] is None else float(summary["final_score"])), note


def fixed_normalization(benchmark: str, env_id: str, raw: float) -> float | None:
    """Procgen easy-mode min-max or ALE human-normalized score; None for a game without constants."""
    table = PROCGEN_EASY if benchmark == "procgen" else ALE_HUMAN
    game = game_of(env_id, table)
    if game is None:
        return None
    low, high = table[game]
    return (raw - low) / (high - low)


def game_of(env_id: str, table: dict) -> str | None:
    """The table's game named in an environment id ("ALE/Qbert-v5", "procgen-bigfish-v0", ...)."""
    letters = re.sub("[^a-z]", "", env_id.lower())
    return next((game for game in sorted(table, key=len, reverse=True) if game.lower() in letters), None)


# ---------------------------------------------------------------------- aggregates (Agarwal et al. 2021)
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


def strata_of(runs: list[Run]) -> list[np.ndarray]:
    games = defaultdict(list)
    for run in runs:
        if run.score is not None:
            games[run.env_id].append(run.score)
    return [np.array(games[g]) for g in sorted(games)]


# ---------------------------------------------------------------------- series helpers
def on_common_grid(series: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray] | None:
    """Series (T, 1 + K) of (step, values...) interpolated onto steps shared by all: (grid, (R, G, K))."""
    series = [s for s in series if s is not None and len(s)]
    if not series:
        return None
    start, stop = max(s[0, 0] for s in series), min(s[-1, 0] for s in series)
    grid = np.linspace(start, stop, GRID_POINTS) if stop > start else np.array([stop])
    values = [np.stack([np.interp(grid, s[:, 0], s[:, k]) for k in range(1, s.shape[1])], axis=-1) for s in series]
    return grid, np.stack(values)


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


def bounds(run: Run) -> np.ndarray | None:
    """(T, 1 + 2K): step, then each cluster's utility and upper confidence bound."""
    tags = [f"ultho/{kind}/{cluster}" for cluster in run.search_space for kind in ("utility", "ucb")]
    if not all(tag in run.series for tag in tags) or len({len(run.series[t]) for t in tags}) != 1:
        return None
    return np.column_stack([run.series[tags[0]][:, 0]] + [run.series[t][:, 1] for t in tags])


# ---------------------------------------------------------------------- figures
def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.]+", "_", text).strip("_")


def method_order(runs: list[Run]) -> list[str]:
    rank = {"ppo": 0, "ultho": 1, "relay": 2}
    keyed = {run.label: (rank[run.kind], run.c or 0, run.window or 0, run.label) for run in runs}
    return sorted(keyed, key=keyed.get)


def save(figure: plt.Figure, out: str, name: str) -> str:
    figure.savefig(os.path.join(out, name), dpi=90)
    plt.close(figure)
    return name


def steps_axis(axes: plt.Axes) -> None:
    axes.xaxis.set_major_formatter(STEPS)
    axes.set_xlabel("environment steps")


def learning_curves(runs: list[Run], benchmark: str, colors: dict, out: str) -> str | None:
    envs = sorted({r.env_id for r in runs if r.curve is not None})
    if not envs:
        return None
    columns = min(4, len(envs))
    rows = -(-len(envs) // columns)
    figure, axes = plt.subplots(rows, columns, figsize=(4.2 * columns, 3.2 * rows + 0.6), squeeze=False,
                                layout="constrained")
    for panel, env_id in zip(axes.flat, envs):
        for label in method_order(runs):
            curves = [r.curve for r in runs if r.env_id == env_id and r.label == label]
            grid = on_common_grid(curves)
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
    for panel in axes.flat[len(envs):]:
        panel.set_visible(False)
    lines = [plt.Line2D([], [], color=colors[label]) for label in method_order(runs)]
    figure.legend(lines, method_order(runs), loc="outside lower center", ncol=min(len(lines), 4), frameon=False)
    figure.suptitle(f"{BENCHMARKS[benchmark]}: training return (mean ± std over seeds)")
    return save(figure, out, f"curves_{benchmark}.png")


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
    counts = np.zeros((len(space), max(len(v) for v in space.values())))
    for chosen in filter(lambda c: c is not None, map(selections, runs)):
        for _, cluster, value in chosen:
            counts[int(cluster), int(value)] += 1
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


def robustness_figure(runs: list[Run], benchmark: str, grid: tuple[set, set], seed: int, reps: int,
                      out: str) -> tuple[str | None, list[str]]:
    """(file name, the (c, W) cells without scored runs)."""
    ultho = [r for r in runs if r.kind == "ultho" and r.score is not None and not r.narrowed]
    if not ultho:
        return None, []
    cs = sorted(grid[0] | {r.c for r in ultho})
    windows = sorted(grid[1] | {r.window for r in ultho})
    figure, axes = plt.subplots(figsize=(max(5.5, 1.6 * len(cs) * len(windows) + 2), 4.4), layout="constrained")
    width, labelled, empty = 0.8 / len(cs), set(), []
    for i, c in enumerate(cs):
        for j, window in enumerate(windows):
            x = j + (i - (len(cs) - 1) / 2) * width
            cell = strata_of([r for r in ultho if r.c == c and r.window == window])
            if not cell:
                empty.append(f"(c={c:g}, W={window})")
                axes.text(x, 0.03, f"c = {c:g}: no runs", rotation=90, ha="center", va="bottom", fontsize=8,
                          color="gray", transform=axes.get_xaxis_transform())
                continue
            point, low, high = (100 * v for v in aggregate_with_interval(cell, "mean", seed, reps))
            axes.bar(x, point, width * 0.9, yerr=[[point - low], [high - point]], color=f"C{i}", capsize=3,
                     label=None if c in labelled else f"c = {c:g}")
            labelled.add(c)
    ppo = strata_of([r for r in runs if r.kind == "ppo"])
    if ppo:
        point, low, high = (100 * v for v in aggregate_with_interval(ppo, "mean", seed, reps))
        axes.axhline(point, color="black", linestyle="--", label="PPO (fixed settings)")
        axes.axhspan(low, high, color="black", alpha=0.08, zorder=0)
    axes.set_xticks(range(len(windows)), [f"W = {w}" for w in windows])
    axes.set_xlim(-0.5, len(windows) - 0.5)
    axes.set_xlabel("sliding window W")
    axes.set_ylabel("normalized score (%), mean with 95% CI")
    axes.set_title(f"{BENCHMARKS[benchmark]}: ULTHO over the (c, W) grid", fontsize=11)
    axes.legend(loc="upper center", bbox_to_anchor=(0.5, -0.15), ncol=len(cs) + 1, frameon=False)
    return save(figure, out, f"robustness_{benchmark}.png"), empty


# ---------------------------------------------------------------------- report
def percent(point: float, low: float, high: float) -> str:
    return f"{100 * point:.1f} [{100 * low:.1f}, {100 * high:.1f}]"


def budget_text(runs: list[Run]) -> str:
    low, high = min(r.budget for r in runs), max(r.budget for r in runs)
    return f"{low:,}" if low == high else f"{low:,}–{high:,}"


def benchmark_section(study: Study, benchmark: str, args: argparse.Namespace, rows: list[dict]) -> list[str]:
    seed, reps, out = args.seed, args.reps, args.out
    runs = [r for r in study.runs if r.benchmark == benchmark]
    methods = method_order(runs)
    palette = plt.get_cmap("tab10" if len(methods) <= 10 else "tab20")
    colors = {label: palette(i) for i, label in enumerate(methods)}
    lines = [f"## {BENCHMARKS[benchmark]}", ""]

    lines += ["### Learning curves", ""]
    curves = learning_curves(runs, benchmark, colors, out)
    lines += [f"![learning curves]({curves})", "",
              "Episodic return of the training episodes against environment steps; the line is the mean and the "
              "band one standard deviation over seeds. Relay-ULTHO shows the winning COI/NOI run.", ""] if curves \
        else ["No run has TensorBoard return curves.", ""]

    envs = sorted({r.env_id for r in runs})
    lines += ["### Aggregate scores", "",
              "| method | games | runs | mean (%) [95% CI] | IQM (%) [95% CI] | budget per run (steps) |",
              "|---|---|---|---|---|---|"]
    normalization = NORMALIZATION.get(benchmark, MIN_MAX_OVER_RUNS)
    for label in methods:
        members = [r for r in runs if r.label == label]
        strata = strata_of(members)
        if not strata:
            lines.append(f"| {label} | 0 | 0 | – | – | {budget_text(members)} |")
            continue
        mean, iqm = (aggregate_with_interval(strata, name, seed, reps) for name in AGGREGATES)
        lines.append(f"| {label} | {len(strata)} | {sum(map(len, strata))} | {percent(*mean)} | {percent(*iqm)} | "
                     f"{budget_text(members)} |")
        rows.append({"benchmark": benchmark, "method": label, "games": len(strata), "runs": sum(map(len, strata)),
                     "mean": mean[0], "mean_low": mean[1], "mean_high": mean[2], "iqm": iqm[0], "iqm_low": iqm[1],
                     "iqm_high": iqm[2], "budget_steps_min": min(r.budget for r in members),
                     "budget_steps_max": max(r.budget for r in members), "normalization": normalization})
    notes = sorted({f"`{r.path}`: {r.score_note}" for r in runs if r.score_note})
    lines += ["", f"Score: {normalization}. Mean and IQM (interquartile mean) over all games x seeds, 95% "
              f"stratified-bootstrap percentile intervals ({reps} resamples of the seeds within each game, "
              f"seed {seed}). "
              + ("Relay-ULTHO: one score per relay (its winner's); its budget is the three runs'. "
                 if any(r.kind == "relay" for r in runs) else "")
              + "Also in [aggregate.csv](aggregate.csv).", ""] + [f"- {n}" for n in notes] + [""] * bool(notes)

    lines += ["### Coverage", "", "Scored runs per environment and method (– = none):", "",
              "| method | " + " | ".join(envs) + " |", "|---|" + "---|" * len(envs)]
    for label in methods:
        counts = Counter(r.env_id for r in runs if r.label == label and r.score is not None)
        lines.append(f"| {label} | " + " | ".join(str(counts[e]) if counts[e] else "–" for e in envs) + " |")
    lines.append("")

    ultho_methods = [m for m in methods if any(r.label == m and r.kind == "ultho" for r in runs)]
    if ultho_methods:
        lines += ["### Decision process and confidence bounds", "",
                  "Left: each cluster's cumulative share of the selections so far (mean over runs); right: the "
                  "share of each value among its cluster's selections (pooled over runs). Bounds: each cluster's "
                  "utility U (mean of its last W credits, Eq. 6) and U + c·sqrt(ln i / N), the bound Eq. 4 "
                  "maximises, mean over runs.", ""]
    for label in ultho_methods:
        members = [r for r in runs if r.label == label]
        drawn = decision_figures(members, f"{BENCHMARKS[benchmark]} {label}", out, slug(f"{benchmark}_{label}"))
        lines += [f"#### {label}", ""] + [f"![{what}]({name})" for what, name in drawn] + [""]
        if not args.per_run:
            continue
        # Named by the path below the directory all runs share, so names stay short and distinct.
        base = os.path.commonpath([os.path.dirname(os.path.abspath(r.path)) for r in study.runs])
        per_run = [(r, per_run_figure(r, os.path.relpath(os.path.abspath(r.path), base), out))
                   for r in sorted(members, key=lambda r: (r.env_id, r.seed))]
        lines += ["Per run: " + ", ".join(f"[{r.env_id} seed {r.seed}]({name})" for r, name in per_run if name), ""]

    robustness, empty = robustness_figure(runs, benchmark, study.grid[benchmark], seed, reps, out)
    if robustness:
        lines += ["### Robustness over (c, W)", "", f"![robustness]({robustness})", "",
                  "Mean normalized score of ULTHO at each (c, W) with its 95% stratified-bootstrap interval; the "
                  "dashed line and grey band are fixed-settings PPO."
                  + (f" No scored ULTHO runs at {', '.join(empty)}." if empty else ""), ""]
    return lines


def write_report(study: Study, args: argparse.Namespace) -> None:
    out = args.out
    os.makedirs(out, exist_ok=True)
    benchmarks = [b for b in BENCHMARKS if any(r.benchmark == b for r in study.runs)]
    lines = ["# ULTHO report", "",
             f"`python ultho_report.py {' '.join(args.paths)} --out {out} --seed {args.seed} --reps {args.reps}`: "
             f"{len(study.runs)} runs ({', '.join(BENCHMARKS[b] for b in benchmarks)}).", ""]
    rows: list[dict] = []
    for benchmark in benchmarks:
        lines += benchmark_section(study, benchmark, args, rows)
    if study.missing or study.warnings:
        lines += ["## Missing and skipped", ""] + [f"- {m}" for m in study.missing]
        lines += [f"- {w}" for w in study.warnings] + [""]
    with open(os.path.join(out, "aggregate.csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["benchmark", "method", "games", "runs", "mean", "mean_low",
                                               "mean_high", "iqm", "iqm_low", "iqm_high", "budget_steps_min",
                                               "budget_steps_max", "normalization"])
        writer.writeheader()
        writer.writerows(rows)
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


class OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        self.exit(2, f"{PROG}: error: {message}\n")


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(
        prog="ultho_report.py", description=__doc__.replace("``", "").split("\n    python")[0],
        epilog="examples:\n  python ultho_report.py runs/ --out report/      # then open report/report.md\n"
               "  python ultho_report.py sweeps/procgen/ runs/my_run --out report/ --seed 1 --no-per-run\n\n"
               "Unreadable or missing run files are named in one warning each on stderr and skipped.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="+", metavar="PATH",
                        help="run directories, relay directories, sweep directories, or folders holding them")
    parser.add_argument("--out", default="report", help="output directory for report.md, aggregate.csv and the "
                        "PNG figures (default: report)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap: the same seed gives the same "
                        "intervals (default: 0)")
    parser.add_argument("--reps", type=int, default=50_000, help="bootstrap resamples (default: 50000, as rliable)")
    parser.add_argument("--no-per-run", dest="per_run", action="store_false", help="skip the per-run decision "
                        "figures (one PNG per ULTHO run, about a second each; the aggregated ones stay)")
    args = parser.parse_args(argv)
    for path in args.paths:
        if not os.path.exists(path):
            parser.error(f"no such path: {path}")
    if args.reps < 1:
        parser.error(f"--reps must be positive, got {args.reps}")

    logger = logging.getLogger("tensorboard")
    logger.setLevel(logging.DEBUG)
    logger.propagate = False  # its own messages would otherwise reach stderr; damage becomes our warning
    logger.addHandler(damaged)

    study = Study()
    study.discover(args.paths)
    if not study.runs and not study.missing:
        parser.error(f"no run found below {', '.join(args.paths)} (no summary.json, relay.json or sweep.json)")
    study.normalize()
    study.label_methods()
    write_report(study, args)
    print(f"{PROG}: wrote {os.path.join(args.out, 'report.md')}", file=sys.stderr)


if __name__ == "__main__":
    main()

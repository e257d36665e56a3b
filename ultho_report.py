"""The paper's figures and tables from ULTHO run directories, in one command.

Reads every run directory below the given paths (TensorBoard events through tensorboard's own reader, or the
``scalars.csv`` of an exported study, ``summary.json``, Relay-ULTHO's ``relay.json`` and ``sweep.py``'s
``sweep.json``), groups the runs by benchmark, environment and method (PPO, ULTHO per (c, W), Relay-ULTHO) and
writes PNG figures plus one ``report.md`` that shows them with the tables:

1. learning curves per environment (mean and standard deviation over seeds, one line per method);
2. per-environment scores: the final score (mean return of the last 100 training episodes) and the
   evaluation score, mean and 95% interval over seeds;
3. the aggregate table: score per method, mean and IQM with 95% stratified-bootstrap intervals over seeds and
   environments (Agarwal et al. 2021), over the environments every method in the table covers; also
   ``aggregate.csv``. Scores are normalized with fixed reference scores, never with the runs present;
4. sample efficiency: the environment steps until a run's running score first reaches a threshold;
5. the decision process: cumulative share of each cluster among the selections, share of each value within
   its cluster, and each cluster's utility and upper confidence bound over training;
6. robustness: the score at every (c, W) of each environment.

``--export-data DIR`` also writes a compact copy of the study (every ``summary.json``, ``relay.json`` and
``sweep.json``, and each run's curves as ``scalars.csv`` instead of its event files) from which the same
report can be redrawn: ``python ultho_report.py DIR --out ...``.

    python ultho_report.py runs/ --out report/
"""

import argparse
import ast
import csv
import itertools
import json
import logging
import math
import os
import re
import shutil
import subprocess
import sys
from collections import defaultdict
from dataclasses import dataclass, field

import matplotlib

matplotlib.use("Agg")  # headless: figures go to files only
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.ticker import EngFormatter
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from ultho_runs import print_error

PROG = "ultho_report.py"

PROCGEN_EASY = {
    "bigfish": (1, 40), "bossfight": (0.5, 13), "caveflyer": (3.5, 12), "chaser": (0.5, 13),
    "climber": (2, 12.6), "coinrun": (5, 10), "dodgeball": (1.5, 19), "fruitbot": (-1.5, 32.4),
    "heist": (3.5, 10), "jumper": (3, 10), "leaper": (3, 10), "maze": (5, 10), "miner": (1.5, 13),
    "ninja": (3.5, 10), "plunder": (4.5, 30), "starpilot": (2.5, 64),
}
"""Procgen easy-mode (R_min, R_max), Cobbe et al. 2020 (docs/paper.md; ppo_ultho_procgen.py keeps a copy)."""

ALE_HUMAN = {
    "BattleZone": (2360.0, 37187.5), "DoubleDunk": (-18.6, -16.4), "NameThisGame": (2292.3, 8049.0),
    "Phoenix": (761.4, 7242.6), "Qbert": (163.9, 13455.0),
}
"""ALE (random, human) scores for human normalization (docs/paper.md; ppo_ultho_atari.py keeps a copy)."""

PYBULLET_REFERENCE = {
    "AntBulletEnv": (362.6, 2865.9), "HalfCheetahBulletEnv": (-1268.9, 2924.7),
    "HopperBulletEnv": (19.9, 2575.1), "Walker2DBulletEnv": (16.7, 2110.0),
}
"""PyBullet (uniform random policy, rl-baselines3-zoo's PPO after 2M steps) returns (docs/paper.md)."""

MINIGRID_RANGE = {"MiniGrid": (0.0, 1.0)}
"""MiniGrid's returns lie in [0, 1] (1 - 0.9 * steps / max_steps on success, else 0): used as they are."""

DMC_RANGE = {re.sub("[^a-z]", "", f"{domain}{task}".lower()): (0.0, 1000.0) for domain, tasks in {
    "acrobot": "swingup swingup_sparse", "ball_in_cup": "catch", "cheetah": "run", "dog": "stand walk trot run fetch",
    "cartpole": "balance balance_sparse swingup swingup_sparse two_poles three_poles",
    "finger": "spin turn_easy turn_hard", "fish": "upright swim", "hopper": "stand hop",
    "humanoid": "stand walk run run_pure_state", "humanoid_CMU": "stand walk run",
    "manipulator": "bring_ball bring_peg insert_ball insert_peg", "pendulum": "swingup", "point_mass": "easy hard",
    "quadruped": "walk run escape fetch", "reacher": "easy hard", "stacker": "stack_2 stack_4",
    "swimmer": "swimmer6 swimmer15", "walker": "stand walk run"}.items() for task in tasks.split()}
"""The DeepMind Control Suite's tasks (DOMAIN-TASK, by their letters): returns lie in [0, 1000] (a reward in
[0, 1] at each of 1000 steps), divided by 1000; not lqr, whose episodes never end and whose reward can be
negative. Keyed by task, not domain, so that gymnasium ids such as HalfCheetah-v5 or Pendulum-v1, which
sac_ultho_dmc.py also runs, get no DMC scale."""

BENCHMARKS = {"procgen": "Procgen", "atari": "ALE", "minigrid": "MiniGrid", "pybullet": "PyBullet", "dmc": "DMC"}
REFERENCES = {"procgen": PROCGEN_EASY, "atari": ALE_HUMAN, "pybullet": PYBULLET_REFERENCE,
              "minigrid": MINIGRID_RANGE, "dmc": DMC_RANGE}
NORMALIZATION = {
    "procgen": "Procgen easy-mode min-max normalized test score, (R - R_min) / (R_max - R_min) with Cobbe et al. "
               "2020's constants",
    "atari": "human-normalized score, (R - random) / (human - random)",
    "pybullet": "(R - random policy) / (rl-baselines3-zoo PPO - random policy), the references of docs/paper.md",
    "minigrid": "the final score as it is (MiniGrid's returns lie in [0, 1])",
    "dmc": "the final score / 1000 (DeepMind Control Suite returns lie in [0, 1000])",
}
RETURN_TAG = "charts/episodic_return"
PAPER_VARIANT = "ucb:level:none"
HPO_METHODS = ("pbt", "pb2", "random")
HPO_NAMES = {"pbt": "PBT", "pb2": "PB2", "random": "random search"}
SCALARS_CSV = "scalars.csv"
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
    kind: str  # "ppo", "ultho", "relay", or an HPO study's method: "pbt", "pb2", "random"
    c: float | None
    window: int | None
    seed: int
    budget: int
    raw_score: float | None
    score_note: str | None = None
    eval_score: float | None = None  # raw mean return of the final evaluation (Procgen: the test levels)
    curve: np.ndarray | None = None  # (T, 2): step, episodic return
    curve_budget: int = 0  # the steps the curve's run trained for (a relay: its winning run's)
    start_offset: int = 0  # steps spent before the curve's run began (a relay: its full ULTHO run's)
    series: dict[str, np.ndarray] = field(default_factory=dict)  # ultho/* tags -> (T, 2)
    search_space: dict[str, list] | None = None
    variant: str = "ucb:level:none"  # the bandit's strategy:credit:scale (summary.json; the paper's when absent)
    value_selections: dict[str, list[int]] | None = None  # credited selections of each value (summary.json)
    utility: str = "value"  # what the bandit was credited with (--ultho-utility; the default when absent)
    settings: dict = field(default_factory=dict)  # the run's command-line settings (summary.json's "settings")
    study: dict | None = None  # an HPO study's study.json (hpo_baselines.py)
    score: float | None = None  # normalized, set by Study.normalize
    label: str = ""  # the method, set by Study.label_methods
    narrowed: bool = False  # ULTHO on a search space other than its benchmark's widest (set with the label)


def finished_on_disk(run_dir: str, method: str) -> bool:
    """Whether a sweep's run ended: its summary.json, or for a relay or study its record saying done."""
    record = "relay.json" if method == "relay" else "study.json" if method in HPO_METHODS else None
    if record is None:
        return os.path.isfile(os.path.join(run_dir, "summary.json"))
    try:
        with open(os.path.join(run_dir, record)) as f:
            return json.load(f).get("status") == "done"
    except (OSError, ValueError, AttributeError):
        return False


class Study:
    """Everything found below the given paths, and what was missing or unreadable."""

    def __init__(self) -> None:
        self.runs: list[Run] = []
        self.warnings: list[str] = []
        self.missing: list[str] = []
        self.absent: list[str] = []  # runs that a sweep, relay or study refers to and that are not there
        self.grid: dict[tuple[str, str], set] = defaultdict(set)  # (benchmark, env_id) -> {(c, W)} of the sweeps
        self._seen: set[str] = set()
        self.files: list[str] = []  # every file the study was read from, for --export-data

    def warn(self, path: str, what: str) -> None:
        """Collected while reading; main() prints them once it knows the report will be drawn."""
        line = f"{path}: {what}"
        if line not in self.warnings:
            self.warnings.append(line)

    def referenced(self, run_dir: str, by: str) -> bool:
        """Whether a run that ``by`` refers to has its summary.json; when not, it is recorded as absent."""
        if os.path.isfile(os.path.join(run_dir, "summary.json")):
            return True
        self.absent.append(f"{run_dir} (referred to by {by})")
        return False

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
        self.files.append(path)
        return data

    def read_scalars(self, run_dir: str) -> dict[str, np.ndarray]:
        """The return curve, the hparams/* and ultho/* series: from the event files, else from scalars.csv."""
        names = os.listdir(run_dir)
        if not any(name.startswith("events.out.tfevents") for name in names):
            if SCALARS_CSV in names:
                return self.read_scalars_csv(os.path.join(run_dir, SCALARS_CSV))
            self.warn(run_dir, "no TensorBoard event files; no curves for this run")
            return {}
        damaged.files.clear()
        accumulator = EventAccumulator(run_dir, size_guidance={"scalars": 0})
        try:
            accumulator.Reload()
            tags = accumulator.Tags()["scalars"]
            series = {tag: np.array([(e.step, e.value) for e in accumulator.Scalars(tag)], dtype=float)
                      for tag in tags if reported_tag(tag)}
        except Exception as err:  # noqa: BLE001  (a damaged file of any kind is skipped, never a traceback)
            self.warn(run_dir, f"TensorBoard events unreadable ({err.__class__.__name__}); no curves for this run")
            return {}
        for event_file in sorted(damaged.files):
            self.warn(event_file, "damaged or truncated TensorBoard events; read up to the damage")
        return series

    def read_scalars_csv(self, path: str) -> dict[str, np.ndarray]:
        try:
            with open(path, newline="") as f:
                rows = list(csv.reader(f))
            header, body = rows[0], rows[1:]
            if header[0] != "step":
                raise ValueError("the first column is not 'step'")
            series = {}
            for k, tag in enumerate(header[1:], start=1):
                # float32 first: TensorBoard stores float32, so both readers give the same numbers.
                points = [(float(row[0]), float(np.float32(row[k]))) for row in body if row[k] != ""]
                series[tag] = np.array(points, dtype=float).reshape(-1, 2)
        except (OSError, ValueError, IndexError) as err:
            self.warn(path, f"unreadable ({err.__class__.__name__}: {err}); no curves for this run")
            return {}
        return series

    # ------------------------------------------------------------------ discovery
    def discover(self, roots: list[str]) -> None:
        sweeps, relays, studies, run_dirs = [], [], [], []
        for root in roots:
            for directory, subdirs, files in os.walk(root):
                subdirs.sort()
                if "sweep.json" in files:
                    sweeps.append(directory)
                if "study.json" in files:
                    studies.append(directory)
                elif "relay.json" in files:
                    relays.append(directory)
                elif "summary.json" in files or SCALARS_CSV in files or \
                        any(f.startswith("events.out.tfevents") for f in files):
                    run_dirs.append(directory)
        for directory in sweeps:
            listed_relays, listed_studies, listed_runs = self.load_sweep(directory)
            relays += listed_relays
            studies += listed_studies
            run_dirs += listed_runs
        owners = [os.path.realpath(d) + os.sep for d in relays + studies]
        for directory in relays:
            self.load_relay(directory)
        for directory in studies:
            self.load_study(directory)
        for directory in run_dirs:
            # A run inside a relay or a study directory is one of its own runs, scored with it.
            if not any(os.path.realpath(directory).startswith(owner) for owner in owners):
                self.load_run(directory)

    def claim(self, path: str) -> bool:
        """False when this directory was already read (given twice, or both found and listed in a sweep)."""
        real = os.path.realpath(path)
        if real in self._seen:
            return False
        self._seen.add(real)
        return True

    def load_sweep(self, directory: str) -> tuple[list[str], list[str], list[str]]:
        path = os.path.join(directory, "sweep.json")
        sweep = self.read_json(path)
        relays, studies, runs = [], [], []
        if sweep is None:
            return relays, studies, runs
        try:
            grid = sweep["grid"]
            # The robustness figure is the paper's bandit over (c, W); a grid of other variants is not a point of it.
            paper_bandit = PAPER_VARIANT in grid.get("variants", [PAPER_VARIANT])
            if paper_bandit and ("ultho" in grid["methods"] or "relay" in grid["methods"]):
                points = grid.get("points") or [[c, w] for c in grid["c"] for w in grid["window"]]
                for script in grid["scripts"]:
                    for env_id in grid["env_ids"]:
                        self.grid[(benchmark_of(script), env_id)].update((float(c), int(w)) for c, w in points)
            for entry in sweep["runs"]:
                where = os.path.join(directory, entry["path"])
                # sweep.json learns of a finished run only when the sweep does: the run's own files decide.
                if entry["status"] != "done" and not finished_on_disk(where, entry["method"]):
                    what = f"sweep run `{entry['name']}` ({entry['method']}, {entry['env_id']}, seed {entry['seed']})"
                    if entry["status"] == "failed":
                        error = f": {entry['error']}" if entry.get("error") else ""
                        self.missing.append(f"{what} failed{error}")
                    else:
                        self.missing.append(f"{what} has not finished (sweep.json: {entry['status']})")
                elif not os.path.isdir(where):
                    self.absent.append(f"{where} (listed as done in {path})")
                    self.warn(where, "listed as done in sweep.json but not there; skipped")
                else:
                    kind = entry["method"]
                    (relays if kind == "relay" else studies if kind in HPO_METHODS else runs).append(where)
        except (KeyError, TypeError, ValueError) as err:
            self.warn(path, f"not in the sweep.json format ({err.__class__.__name__}: {err}); its index is skipped")
        return relays, studies, runs

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
        for role in ("full", "coi", "noi"):
            if relay.get(f"{role}_run"):
                self.referenced(os.path.normpath(os.path.join(directory, relay[f"{role}_run"])), path)
        winner = self.read_summary(winner_dir)
        if winner is None:
            return
        for role in ("coi", "noi"):  # the losing run too, so that --export-data keeps the whole relay
            if relay.get(f"{role}_run") and relay[f"{role}_run"] != relay["winner_run"]:
                self.read_summary(os.path.join(directory, relay[f"{role}_run"]))
        full = self.read_summary(full_dir) or {}
        full_bandit = full.get("bandit") or {}
        run = Run(directory, benchmark, env_id, "relay", full_bandit.get("c"), full_bandit.get("window"), seed,
                  budget, *raw_score(winner, benchmark), eval_score=eval_score(winner),
                  curve=self.read_scalars(winner_dir).get(RETURN_TAG), curve_budget=int(winner["global_step"]),
                  start_offset=int(full.get("global_step") or 0), variant=variant_of(full_bandit))
        self.runs.append(run)

    def load_study(self, directory: str) -> None:
        """An HPO study of hpo_baselines.py, scored by its best trial's final score; its budget is the whole
        population's steps."""
        path = os.path.join(directory, "study.json")
        if not self.claim(directory) or (study := self.read_json(path)) is None:
            return
        try:
            if study["status"] != "done":
                self.missing.append(
                    f"study `{directory}` ({study['method']}, seed {study['seed']}) is {study['status']}")
                return
            method, seed, budget = str(study["method"]), int(study["seed"]), int(study["budget"]["total_steps"])
            if method not in HPO_METHODS:
                raise ValueError(f"unknown method {method!r}")
            trials = {trial["name"]: trial for trial in study["trials"]}
            best_dir = os.path.join(directory, trials[study["best_trial"]]["run_dir"])
            float(study["max_observed_score"]["score"])
            schedule = [(int(part["start_step"]), int(part["end_step"]), dict(part["settings"]))
                        for part in study["best_settings_schedule"]]
        except (KeyError, TypeError, ValueError) as err:
            self.warn(path, f"not in the study.json format ({err.__class__.__name__}: {err}); skipped")
            return
        for trial in trials.values():
            self.referenced(os.path.normpath(os.path.join(directory, trial["run_dir"])), path)
        for trial in trials.values():  # every trial's summary, so that --export-data keeps the whole study
            if trial["run_dir"] != trials[study["best_trial"]]["run_dir"]:
                self.read_summary(os.path.join(directory, trial["run_dir"]))
        best = self.read_summary(best_dir)
        if best is None:
            return
        benchmark = benchmark_of(study["script"])
        study["schedule"] = schedule
        self.runs.append(Run(directory, benchmark, str(best["env_id"]), method, None, None, seed, budget,
                             *raw_score(best, benchmark), eval_score=eval_score(best),
                             curve=self.read_scalars(best_dir).get(RETURN_TAG),
                             curve_budget=int(best["global_step"]), study=study))

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
            eval_score(summary)
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
            eval_score=eval_score(summary), curve=scalars.get(RETURN_TAG), curve_budget=int(summary["global_step"]),
            series={k: v for k, v in scalars.items() if k != RETURN_TAG},
            search_space=bandit["search_space"] if bandit else None,
            variant=variant_of(bandit or {}),
            value_selections=bandit.get("value_selections") if bandit else None,
            utility=str(bandit.get("utility", "value")) if bandit else "value",
            settings=summary.get("settings") or {},
        ))

    # ------------------------------------------------------------------ scores and methods
    def normalize(self) -> None:
        """Fixed reference scores per benchmark: a score never depends on which other runs are present."""
        for run in self.runs:
            if run.raw_score is None:
                self.missing.append(f"`{run.path}` has no score (no training episode ended)")
                continue
            run.score = normalized(run.benchmark, run.env_id, run.raw_score)
            if run.score is None:
                self.missing.append(f"`{run.path}`: no reference scores for {run.env_id}; in the per-environment "
                                    "tables, not in the aggregate")

    def label_methods(self) -> None:
        """PPO, ULTHO (c, W), Relay-ULTHO (c, W); a search space other than the benchmark's widest one is named,
        and so are a credit other than the default, and the settings of fixed-settings runs that differ from
        their script's defaults where the benchmark's fixed-settings runs do not all share them."""
        widest = {}
        for run in self.runs:
            if run.search_space and len(run.search_space) > len(widest.get(run.benchmark, {})):
                widest[run.benchmark] = run.search_space
        for run in self.runs:
            if run.kind == "ppo":
                run.label = baseline_of(run.benchmark) + fixed_settings_text(run, self.runs)
                continue
            if run.kind in HPO_METHODS:
                run.label = (f"random search ({run.study.get('samples')} samples)" if run.kind == "random" else
                             f"{HPO_NAMES[run.kind]} (population {run.study.get('population')})")
                continue
            strategy = run.variant.split(":")[0]
            if run.c is None or strategy == "round-robin":  # a rotation uses neither c nor W
                setting = ""
            else:  # Thompson sampling and Exp3 do not use c
                setting = f" (c={run.c:g}, W={run.window})" if strategy == "ucb" else f" (W={run.window})"
            variant = "" if run.variant == PAPER_VARIANT else " " + run.variant.replace(":", "/")
            if run.utility != script_defaults(run.benchmark).get("ultho_utility", run.utility):
                variant += f" {run.utility}"
            name = "ULTHO" if run.kind == "ultho" else "Relay-ULTHO"
            if strategy == "round-robin":
                name, variant = ("Round robin" if run.kind == "ultho" else "Relay round robin"), ""
            run.label = name + variant + setting
            run.narrowed = bool(run.search_space) and run.search_space != widest[run.benchmark]
            if run.narrowed:
                run.label += " on " + ", ".join(f"{k}={'/'.join(map(str, v))}" for k, v in run.search_space.items())


NOT_SETTINGS = ("seed", "env_id", "run_name", "exp_name", "runs_dir", "resume", "init_from", "quiet",
                "total_timesteps")
"""Fields of a run's settings that say which run it is, not how it learns: never named in a method's label."""


def fixed_settings_text(run: Run, runs: list[Run]) -> str:
    """", update_epochs=5" for a fixed-settings run whose settings differ from its script's defaults, naming only
    the settings on which the benchmark's fixed-settings runs disagree (so one set of runs keeps the plain name)."""
    peers = [r for r in runs if r.kind == run.kind and r.benchmark == run.benchmark]
    defaults = script_defaults(run.benchmark)
    named = []
    for key, value in run.settings.items():
        if key in NOT_SETTINGS or key not in defaults or value == defaults[key]:
            continue
        if any(peer.settings.get(key, defaults[key]) != value for peer in peers):
            named.append(f"{key}={value}")
    return (", " + ", ".join(named)) if named else ""


_DEFAULTS: dict[str, dict] = {}


def script_defaults(benchmark: str) -> dict:
    """The literal defaults of a benchmark's script's Args dataclass, read from its source beside this module
    (empty when the script is not there)."""
    if benchmark not in _DEFAULTS:
        stem = "sac_ultho_dmc" if benchmark == "dmc" else f"ppo_ultho_{benchmark}"
        path = os.path.join(os.path.dirname(os.path.abspath(__file__)), f"{stem}.py")
        defaults = {}
        if os.path.exists(path):
            with open(path, encoding="utf-8") as f:
                tree = ast.parse(f.read())
            for node in tree.body:
                if isinstance(node, ast.ClassDef) and node.name == "Args":
                    for item in node.body:
                        if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name) and item.value:
                            try:
                                defaults[item.target.id] = ast.literal_eval(item.value)
                            except ValueError:
                                pass  # not a literal (e.g. the search space's names): never named
        _DEFAULTS[benchmark] = defaults
    return _DEFAULTS[benchmark]


def variant_of(bandit: dict) -> str:
    """strategy:credit:scale of a summary's bandit; a summary that names none is the paper's bandit."""
    return ":".join(str(bandit.get(key, default)) for key, default in zip(("strategy", "credit", "scale"),
                                                                          PAPER_VARIANT.split(":")))


def reported_tag(tag: str) -> bool:
    """The tags the report draws from: the return, the settings schedule and the cluster-level bandit series."""
    if tag == RETURN_TAG or tag.startswith("hparams/") or tag.startswith("ultho/selected_") or tag == "ultho/credit":
        return True
    return tag.startswith("ultho/") and tag.count("/") == 2  # ultho/<kind>/<cluster>, not its per-value tags


def benchmark_of(script: str) -> str:
    """The benchmark of a script name, with or without ".py" (summary.json leaves it out, the indexes keep it)."""
    match = re.fullmatch(r"(?:ppo|sac)_ultho_(\w+?)(?:\.py)?", os.path.basename(str(script)))
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


def eval_score(summary: dict) -> float | None:
    """The final evaluation's mean return (fresh episodes of the final policy; Procgen: the test levels)."""
    evaluation = summary.get("eval") or {}
    value = evaluation.get("mean_return")
    return None if value is None else float(value)


def reference_of(benchmark: str, env_id: str) -> tuple[float, float] | None:
    """The fixed (low, high) reference scores of an environment: the score is (R - low) / (high - low)."""
    table = REFERENCES[benchmark]
    game = game_of(env_id, table)
    return None if game is None else table[game]


def baseline_of(benchmark: str) -> str:
    """The name of a benchmark's fixed-settings runs (the script with --no-ultho)."""
    return "SAC" if benchmark == "dmc" else "PPO"


def normalized(benchmark: str, env_id: str, raw: float) -> float | None:
    """The score on the benchmark's fixed scale; None for an environment without reference scores."""
    reference = reference_of(benchmark, env_id)
    if reference is None:
        return None
    low, high = reference
    return (raw - low) / (high - low)


def game_of(env_id: str, table: dict) -> str | None:
    """The table's game named in an environment id ("ALE/Qbert-v5", "procgen-bigfish-v0", ...)."""
    def alphanumeric(name: str) -> str:  # digits kept: Walker2DBulletEnv-v0 names Walker2DBulletEnv
        return re.sub("[^a-z0-9]", "", name.lower())

    return next((game for game in sorted(table, key=len, reverse=True)
                 if alphanumeric(game) in alphanumeric(env_id)), None)


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


# ---------------------------------------------------------------------- sample efficiency
def steps_to_threshold(curve: np.ndarray | None, benchmark: str, env_id: str, threshold: float,
                       window: int) -> float | None:
    """The first logged step at which the running score reaches ``threshold``, else None.

    The running score is the mean of the last ``window`` logged training returns (each the mean return of the
    episodes that ended in one iteration), on the benchmark's fixed scale, so a single lucky iteration does not
    count as solving the task.
    """
    reference = reference_of(benchmark, env_id)
    if curve is None or not len(curve) or reference is None:
        return None
    low, high = reference
    scores = (curve[:, 1] - low) / (high - low)
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


def aligned_series(run: Run, tags: list[str]) -> np.ndarray | None:
    """(T, 1 + len(tags)): step, then each tag's value; None unless the run logged every tag equally often."""
    if not tags or not all(tag in run.series for tag in tags) or len({len(run.series[t]) for t in tags}) != 1:
        return None
    return np.column_stack([run.series[tags[0]][:, 0]] + [run.series[t][:, 1] for t in tags])


def bounds(run: Run) -> np.ndarray | None:
    """(T, 1 + 2K): step, then each cluster's utility and upper confidence bound."""
    return aligned_series(run, [f"ultho/{kind}/{cluster}" for cluster in run.search_space
                                for kind in ("utility", "ucb")])


# ---------------------------------------------------------------------- figures
def slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.]+", "_", text).strip("_")


def method_order(runs: list[Run]) -> list[str]:
    rank = {"ppo": 0, "ultho": 1, "relay": 2, "pbt": 3, "pb2": 4, "random": 5}
    keyed = {run.label: (rank[run.kind], run.variant != PAPER_VARIANT, run.variant, run.c or 0, run.window or 0,
                         run.label) for run in runs}
    return sorted(keyed, key=keyed.get)


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


def value_counts(runs: list[Run]) -> np.ndarray:
    """(clusters, most values): how often each value was selected, pooled over the runs."""
    space = runs[0].search_space
    counts = np.zeros((len(space), max(len(v) for v in space.values())))
    for chosen in filter(lambda c: c is not None, map(selections, runs)):
        for _, cluster, value in chosen:
            counts[int(cluster), int(value)] += 1
    return counts


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


# ---------------------------------------------------------------------- report
def percent(point: float, low: float, high: float) -> str:
    return f"{100 * point:.1f} [{100 * low:.1f}, {100 * high:.1f}]"


def number(value: float) -> str:
    """A raw score in the per-environment tables: three significant digits, at least two decimals."""
    return f"{value:.2f}" if abs(value) < 100 else f"{value:,.0f}"


def mean_with_interval(values: list[float], seed: int, reps: int) -> str:
    """``mean [low, high] (n)``: a percentile bootstrap interval of the mean over seeds."""
    if not values:
        return "–"
    point, low, high = aggregate_with_interval([np.array(values)], "mean", seed, reps)
    return f"{number(point)} [{number(low)}, {number(high)}] ({len(values)})"


def budget_text(runs: list[Run]) -> str:
    low, high = min(r.budget for r in runs), max(r.budget for r in runs)
    return f"{low:,}" if low == high else f"{low:,}–{high:,}"


def per_environment_table(runs: list[Run], methods: list[str], envs: list[str], value, seed: int,
                          reps: int) -> list[str]:
    lines = ["| method | " + " | ".join(envs) + " |", "|---|" + "---|" * len(envs)]
    for label in methods:
        cells = [mean_with_interval([v for r in runs if r.label == label and r.env_id == env
                                     and (v := value(r)) is not None], seed, reps) for env in envs]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return lines + [""]


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
    lines += ["### Scores per environment", "",
              f"{'Test score' if benchmark == 'procgen' else 'Final score'}: "
              + ("mean return on the full level distribution (the paper's Procgen measure). " if benchmark == "procgen"
                 else "mean return of the last 100 training episodes (the paper's measure). ")
              + "Each cell: mean over seeds [95% percentile-bootstrap interval] (number of runs), raw returns; "
              "Relay-ULTHO is scored by its winning run.", ""]
    lines += per_environment_table(runs, methods, envs, lambda r: r.raw_score, seed, reps)
    lines += ["Evaluation score: mean return of fresh episodes of the final policy on environment seeds never used "
              "in training (`summary.json`'s `eval`).", ""]
    lines += per_environment_table(runs, methods, envs, lambda r: r.eval_score, seed, reps)

    normalization = NORMALIZATION[benchmark]
    lines += ["### Aggregate scores", "", f"Score: {normalization}. Mean and IQM (interquartile mean) over "
              f"environments x seeds, 95% stratified-bootstrap percentile intervals ({reps} resamples of the seeds "
              f"within each environment, seed {seed}). Each table compares only methods with runs on every one of its "
              "environments. "
              + ("Relay-ULTHO: one score per relay (its winner's); its budget is the three runs'. "
                 if any(r.kind == "relay" for r in runs) else "")
              + ("PBT, PB2, random search: one score per study, the final score of its best trial; its budget is "
                 "the whole population's steps. " if any(r.kind in HPO_METHODS for r in runs) else "")
              + "Also in [aggregate.csv](aggregate.csv).", ""]
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
            lines.append(f"| {label} | {len(strata)} | {count} | {percent(*mean)} | {percent(*iqm)} | "
                         f"{budget_text(members)} |")
            rows.append({"benchmark": benchmark, "method": label, "environments": " ".join(group_envs),
                         "games": len(strata), "runs": count, "mean": mean[0], "mean_low": mean[1],
                         "mean_high": mean[2], "iqm": iqm[0], "iqm_low": iqm[1], "iqm_high": iqm[2],
                         "budget_steps_min": min(r.budget for r in members),
                         "budget_steps_max": max(r.budget for r in members), "normalization": normalization})
        lines.append("")
    notes = sorted({f"`{r.path}`: {r.score_note}" for r in runs if r.score_note})
    lines += [f"- {n}" for n in notes] + [""] * bool(notes)

    threshold, window = args.solve_threshold, args.solve_window
    efficiency = efficiency_figure(runs, benchmark, colors, threshold, window, out)
    if efficiency:
        relays = any(r.kind == "relay" for r in runs)
        ppo = [r for r in runs if r.kind == "ppo"]
        paired = relays and len(ppo) > len({r.env_id for r in ppo})
        baseline = baseline_of(benchmark)
        lines += ["### Sample efficiency", "",
                  f"Steps to solve: the first environment step at which a run's running score (the mean of its last "
                  f"{window} logged training returns, each the mean return of the episodes that ended in one "
                  f"iteration, on the scale above) reaches {threshold:g}. Each cell: the mean over runs, a run that "
                  "never reached it counted with its whole budget (then the mean is a lower bound, marked ≥), and "
                  "(runs that reached it / runs)."
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
        lines += ["", f"![sample efficiency]({efficiency})", ""]
        if paired:
            selected = [(label, [r.score for r in members if r.score is not None]) for label, members in rows_of
                        if label in (baseline, f"{baseline}, better of 2 seeds") or members[0].kind == "relay"]
            lines += ["Final score of the scored runs (mean over runs, on the scale above): "
                      + "; ".join(f"{label} {100 * np.mean(scores):.1f}%" for label, scores in selected if scores)
                      + ".", ""]
        areas = [(label, [r for r in members if normalized_area(r) is not None]) for label, members in rows_of]
        if any(members for _, members in areas):
            lines += ["Area under the normalized learning curve divided by its length (the mean score over training; "
                      "1.0 = the reference all along). Each cell: mean over runs [95% percentile-bootstrap interval] "
                      "(runs).", "", "| method | " + " | ".join(envs) + " | all |", "|---|" + "---|" * (len(envs) + 1)]
            for label, members in areas:
                cells = [mean_with_interval([normalized_area(r) for r in members if r.env_id == env], seed, reps)
                         for env in envs]
                cells.append(mean_with_interval([normalized_area(r) for r in members], seed, reps))
                lines.append(f"| {label} | " + " | ".join(cells) + " |")
            lines.append("")

    studies = sorted((r for r in runs if r.kind in HPO_METHODS), key=lambda r: (method_order(runs).index(r.label),
                                                                              r.env_id, r.seed))
    if studies:
        lines += ["### HPO baselines", "",
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
        schedule = schedule_figure(runs, benchmark, out)
        if schedule:
            lines += [f"![settings schedules]({schedule})", "",
                      "The settings behind each study's best final network (PBT and PB2 follow every exploit back "
                      "into the trial it copied; random search keeps one setting), beside the settings in force in "
                      "one ULTHO run per method (its lowest seed), on each environment's first study.", ""]

    ultho_methods = [m for m in methods if any(r.label == m and r.kind == "ultho" for r in runs)]
    if ultho_methods:
        lines += ["### Decision process and confidence bounds", "",
                  "Left: each cluster's cumulative share of the selections so far (mean over runs); right: the "
                  "share of each value among its cluster's selections (pooled over runs). Bounds: each cluster's "
                  "utility U (mean of its last W credits, Eq. 6) and U + c·sqrt(ln i / N), the bound Eq. 4 "
                  "maximises, mean over runs. The tables: the credited selections of each value, pooled over the "
                  "runs; then each cluster's share of them on each environment, pooled over its runs (in brackets "
                  "the lowest and highest share of a single run), and the bonus / utility spread: over the second "
                  "half of each run, the median of the clusters' mean UCB bonus c·sqrt(ln i / N) divided by the "
                  "spread of their utilities in the bound's units, the median over the runs; above 1 the bonus "
                  "outweighs what separates the clusters and they are taken in turn, well below 1 the bandit "
                  "follows the utilities (– for strategies without a bonus). Last, per run, the value each cluster "
                  "held for the most iterations and the share of the iterations it held it (a cluster the bandit "
                  "stopped choosing keeps the value it was last given), beside the run's final score.", ""]
    for label in ultho_methods:
        members = [r for r in runs if r.label == label]
        drawn = decision_figures(members, f"{BENCHMARKS[benchmark]} {label}", out, slug(f"{benchmark}_{label}"))
        lines += [f"#### {label}", ""] + [f"![{what}]({name})" for what, name in drawn] + [""]
        lines += selection_table(members) + [""]
        lines += decisions_by_environment(members) + [""]
        lines += settings_in_force(members) + [""]
        if not args.per_run:
            continue
        # Named by the path below the directory all runs share, so names stay short and distinct.
        base = os.path.commonpath([os.path.dirname(os.path.abspath(r.path)) for r in study.runs])
        per_run = [(r, per_run_figure(r, os.path.relpath(os.path.abspath(r.path), base), out))
                   for r in sorted(members, key=lambda r: (r.env_id, r.seed))]
        lines += ["Per run: " + ", ".join(f"[{r.env_id} seed {r.seed}]({name})" for r, name in per_run if name), ""]

    robustness, empty = robustness_figure(runs, benchmark, study.grid, seed, reps, out)
    if robustness:
        lines += ["### Robustness over (c, W)", "", f"![robustness]({robustness})", "",
                  "Mean score of ULTHO at each (c, W) of each environment with its 95% percentile-bootstrap interval "
                  "over seeds; the dashed line and grey band are fixed-settings "
                  f"{baseline_of(benchmark)} on that environment."
                  + (f" No scored ULTHO runs at {', '.join(empty)}." if empty else ""), ""]
    return lines


def selection_table(runs: list[Run]) -> list[str]:
    """The credited selections of each value (summary.json), pooled over the runs, and how many runs credited
    every value exactly equally often (a strict rotation: the bandit's choices did not depend on its credits)."""
    counted = [r for r in runs if r.value_selections]
    if not counted:
        return []
    space = counted[0].search_space
    pooled = {cluster: np.sum([r.value_selections[cluster] for r in counted], axis=0) for cluster in space}
    total = sum(counts.sum() for counts in pooled.values())
    rotations = sum(len({n for counts in r.value_selections.values() for n in counts}) == 1 for r in counted)
    lines = ["| cluster | credited selections (share) | per value |", "|---|---|---|"]
    for cluster, values in space.items():
        counts = pooled[cluster]
        lines.append(f"| {cluster} | {counts.sum():,} ({100 * counts.sum() / total:.1f}%) | "
                     + ", ".join(f"{v:g}: {n:,}" for v, n in zip(values, counts)) + " |")
    return lines + ["", f"Pooled over {len(counted)} runs. Runs that credited every value exactly equally often "
                        f"(a strict rotation): {rotations} of {len(counted)}."]


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


def write_report(study: Study, args: argparse.Namespace) -> None:
    out = args.out
    os.makedirs(out, exist_ok=True)
    benchmarks = [b for b in BENCHMARKS if any(r.benchmark == b for r in study.runs)]
    lines = ["# ULTHO report", "",
             f"`python ultho_report.py {' '.join(args.paths)} --out {out} --seed {args.seed} --reps {args.reps}"
             f" --solve-threshold {args.solve_threshold:g} --solve-window {args.solve_window}"
             f"{'' if args.per_run else ' --no-per-run'}{' --allow-missing' if args.allow_missing else ''}`: "
             f"{len(study.runs)} runs ({', '.join(BENCHMARKS[b] for b in benchmarks)}).", ""]
    rows: list[dict] = []
    for benchmark in benchmarks:
        lines += benchmark_section(study, benchmark, args, rows)
    if study.missing or study.warnings:
        lines += ["## Missing and skipped", ""] + [f"- {m}" for m in study.missing]
        lines += [f"- {w}" for w in study.warnings] + [""]
    with open(os.path.join(out, "aggregate.csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=["benchmark", "method", "environments", "games", "runs", "mean",
                                               "mean_low", "mean_high", "iqm", "iqm_low", "iqm_high",
                                               "budget_steps_min", "budget_steps_max", "normalization"])
        writer.writeheader()
        writer.writerows(rows)
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


# ---------------------------------------------------------------------- compact export
def export_data(study: Study, roots: list[str], out: str) -> int:
    """Copies what the report read into ``out``: JSON files as they are, each run's curves as scalars.csv.

    Each root keeps its own folder (its base name) with its layout below, so sweep.json's and relay.json's
    relative paths still hold; a relay's absolute ``full_run`` inside a root becomes relative. Returns the
    number of bytes written.
    """
    roots = [os.path.realpath(r) for r in roots]
    names = [os.path.basename(r.rstrip(os.sep)) or "root" for r in roots]
    if len(set(names)) != len(names):
        raise ValueError(f"--export-data: the paths {', '.join(roots)} share a folder name")

    def target(path: str) -> str | None:
        real = os.path.realpath(path)
        for root, name in zip(roots, names):
            if real == root or real.startswith(root + os.sep):
                return os.path.normpath(os.path.join(out, name, os.path.relpath(real, root)))
        return None

    written = 0
    for path in dict.fromkeys(study.files):
        destination = target(path)
        if destination is None:
            continue
        os.makedirs(os.path.dirname(destination), exist_ok=True)
        if os.path.basename(path) == "relay.json":
            with open(path) as f:
                relay = json.load(f)
            if os.path.isabs(relay.get("full_run") or "") and (full := target(relay["full_run"])):
                relay["full_run"] = os.path.relpath(full, os.path.dirname(destination))
            with open(destination, "w") as f:
                json.dump(relay, f, indent=1)
        else:
            shutil.copyfile(path, destination)
        written += os.path.getsize(destination)
        run_dir = os.path.dirname(path)
        if os.path.basename(path) == "summary.json" and (series := study.read_scalars(run_dir)):
            written += write_scalars_csv(series, os.path.join(os.path.dirname(destination), SCALARS_CSV))
    return written


def ignored_by_git(folder: str) -> list[str]:
    """The files below ``folder`` that git would leave out of a commit (none outside a git work tree)."""
    files = [os.path.join(d, name) for d, _, names in os.walk(folder) for name in names]
    try:
        result = subprocess.run(["git", "-C", folder, "check-ignore", "--no-index", "--stdin"], capture_output=True,
                                text=True, input="\n".join(os.path.abspath(f) for f in files))
    except OSError:  # no git
        return []
    return result.stdout.splitlines() if result.returncode == 0 else []


def write_scalars_csv(series: dict[str, np.ndarray], path: str) -> int:
    """One row per logged step, one column per tag; float32 values (TensorBoard's) written to round-trip."""
    tags = sorted(series)
    steps = sorted({int(step) for tag in tags for step in series[tag][:, 0]})
    position = {step: i for i, step in enumerate(steps)}
    table = [[""] * len(tags) for _ in steps]
    for k, tag in enumerate(tags):
        for step, value in series[tag]:
            table[position[int(step)]][k] = "nan" if math.isnan(value) else f"{np.float32(value)!r}".removeprefix(
                "np.float32(").removesuffix(")")
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["step", *tags])
        writer.writerows([[step, *row] for step, row in zip(steps, table)])
    return os.path.getsize(path)


class OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        print_error(PROG, message)
        self.exit(2)


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(
        prog=PROG, description=__doc__.replace("``", "").split("\n    python")[0],
        epilog="examples:\n  python ultho_report.py runs/ --out report/      # then open report/report.md\n"
               "  python ultho_report.py sweeps/procgen/ runs/my_run --out report/ --seed 1 --no-per-run\n"
               "  python ultho_report.py runs/sweep-minigrid --out results/minigrid \\\n"
               "      --export-data results/minigrid/data\n"
               "\nUnreadable or missing run files are named in one warning each on stderr and skipped.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="+", metavar="PATH",
                        help="run directories, relay directories, sweep directories, or folders holding them")
    parser.add_argument("--out", default="report", help="output directory for report.md, aggregate.csv and the "
                        "PNG figures (default: report)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap: the same seed gives the same "
                        "intervals (default: 0)")
    parser.add_argument("--reps", type=int, default=50_000, help="bootstrap resamples (default: 50000, as rliable)")
    parser.add_argument("--no-per-run", dest="per_run", action="store_false", help="skip the per-run decision "
                        "figures (one PNG per ULTHO run; the aggregated ones stay)")
    parser.add_argument("--solve-threshold", type=float, default=0.9, metavar="SCORE",
                        help="the score (on the aggregate table's scale) a run must reach to count as solved in the "
                             "sample-efficiency table (default: 0.9, e.g. MiniGrid return 0.9)")
    parser.add_argument("--solve-window", type=int, default=5, metavar="N",
                        help="logged iterations the running score averages (default: 5)")
    parser.add_argument("--allow-missing", action="store_true", help="draw a partial report when a sweep, relay or "
                        "study refers to runs that are not there (default: stop, naming the first one)")
    parser.add_argument("--export-data", metavar="DIR", help="also write a compact copy of the study to DIR "
                        "(summaries, relay and sweep indexes, each run's curves as scalars.csv), enough to redraw "
                        "the report")
    args = parser.parse_args(argv)
    for path in args.paths:
        if not os.path.exists(path):
            parser.error(f"no such path: {path}")
    if args.reps < 1:
        parser.error(f"--reps must be positive, got {args.reps}")
    if args.solve_window < 1:
        parser.error(f"--solve-window must be positive, got {args.solve_window}")
    if not math.isfinite(args.solve_threshold):
        parser.error(f"--solve-threshold must be a finite number, got {args.solve_threshold}")
    if args.export_data and os.path.exists(args.export_data) and os.listdir(args.export_data):
        parser.error(f"--export-data {args.export_data}: the folder exists and is not empty")
    names = [os.path.basename(os.path.realpath(p).rstrip(os.sep)) for p in args.paths]
    if args.export_data and len(set(names)) != len(names):
        parser.error(f"--export-data: the paths {' '.join(args.paths)} share a folder name")

    logger = logging.getLogger("tensorboard")
    logger.setLevel(logging.DEBUG)
    logger.propagate = False  # its own messages would otherwise reach stderr; damage becomes our warning
    logger.addHandler(damaged)

    study = Study()
    study.discover(args.paths)
    if study.absent and not args.allow_missing:
        more = f" and {len(study.absent) - 1} more" if len(study.absent) > 1 else ""
        parser.error(f"missing run {study.absent[0]}{more}; --allow-missing draws a partial report")
    for line in study.warnings:
        print(f"{PROG}: warning: {line}", file=sys.stderr)
    if not study.runs and not study.missing:
        parser.error(f"no run found below {', '.join(args.paths)} (no summary.json, relay.json or sweep.json)")
    study.normalize()
    study.label_methods()
    write_report(study, args)
    print(f"{PROG}: wrote {os.path.join(args.out, 'report.md')}", file=sys.stderr)
    if args.export_data:
        size = export_data(study, args.paths, args.export_data)
        print(f"{PROG}: wrote {size / 1e6:.1f} MB of study data to {args.export_data}", file=sys.stderr)
        if ignored := ignored_by_git(args.export_data):
            print(f"{PROG}: warning: git ignores {len(ignored)} of the exported files (e.g. {ignored[0]}): a commit "
                  "would leave them out", file=sys.stderr)


if __name__ == "__main__":
    main()

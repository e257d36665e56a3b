"""Reading a study: the runs below the given paths, what was missing or unreadable, and each run's method.

A study is whatever the paths hold: training runs (``summary.json`` with TensorBoard event files, or the
``scalars.csv`` of an exported study), Relay-ULTHO directories (``relay.json``, scored by the winning run),
HPO studies of hpo_baselines.py (``study.json``, scored by the best trial) and sweeps (``sweep.json``, which
lists runs and the (c, W) grid they belong to). ``Study`` finds and reads them into ``Run`` entries, keeps
every file it read (for ``--export-data``) and collects warnings instead of stopping on damaged input; then
``Study.normalize`` puts each score on its benchmark's fixed scale and ``Study.label_methods`` names each run's
method (PPO, ULTHO (c, W), Relay-ULTHO, ...), the groups every table and figure is drawn by.
"""

import csv
import json
import logging
import os
import re
from collections import defaultdict
from dataclasses import dataclass, field

import numpy as np
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from ultho_runs import script_literals
from ultho_reporting.references import BENCHMARKS, normalized

RETURN_TAG = "charts/episodic_return"
PAPER_VARIANT = "ucb:level:none"
BANDIT_CHANGING_FLAGS = ("--ultho-utility", "--ultho-clusters", "--ultho-strategy", "--ultho-credit", "--ultho-scale")
"""A sweep's extra arguments that make its ULTHO runs something other than the paper's bandit."""
HPO_METHODS = ("pbt", "pb2", "random")
HPO_NAMES = {"pbt": "PBT", "pb2": "PB2", "random": "random search"}
SCALARS_CSV = "scalars.csv"
CHECKOUT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
"""The checkout this package lies in, beside the scripts whose defaults name the fixed-settings runs."""


class DamagedEventFiles(logging.Handler):
    """tensorboard's reader reports a truncated or corrupt record only as a debug log line; collect them."""

    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.files: set[str] = set()

    def emit(self, record: logging.LogRecord) -> None:
        if str(record.msg).startswith("Truncated record in"):
            self.files.add(str(record.args[0]))


damaged = DamagedEventFiles()


def catch_tensorboard_damage() -> None:
    """Sends tensorboard's log to ``damaged`` alone: its own messages would otherwise reach stderr, and the
    damage it reports becomes one warning per file."""
    logger = logging.getLogger("tensorboard")
    logger.setLevel(logging.DEBUG)
    logger.propagate = False
    logger.addHandler(damaged)


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
    curve_budget: int = 0  # the steps the curve's run trained for, or was given if it diverged (a relay: its winner's)
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
    diverged: dict | None = None  # where the scored run's loss became non-finite (summary.json's "diverged")
    grid: bool = False  # one of a sweep's fixed settings (--methods grid): only the landscape section shows it


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
        self.grid_runs: set[str] = set()  # real paths of the runs a sweep.json lists as its grid of fixed settings
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
            # The robustness figure is the paper's bandit over (c, W); a grid of other variants, credits or search
            # spaces is not a point of it.
            paper_bandit = PAPER_VARIANT in grid.get("variants", [PAPER_VARIANT]) and not any(
                str(token).startswith(BANDIT_CHANGING_FLAGS) for token in grid.get("extra_args") or [])
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
                    if kind == "grid":
                        self.grid_runs.add(os.path.realpath(where))
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
                  curve=self.read_scalars(winner_dir).get(RETURN_TAG), curve_budget=curve_budget_of(winner),
                  start_offset=int(full.get("global_step") or 0), variant=variant_of(full_bandit),
                  diverged=diverged_of(winner))
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
                             curve_budget=curve_budget_of(best), study=study, diverged=diverged_of(best)))

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
            diverged_of(summary)
            curve_budget_of(summary)
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
            eval_score=eval_score(summary), curve=scalars.get(RETURN_TAG), curve_budget=curve_budget_of(summary),
            series={k: v for k, v in scalars.items() if k != RETURN_TAG},
            search_space=bandit["search_space"] if bandit else None,
            variant=variant_of(bandit or {}),
            value_selections=bandit.get("value_selections") if bandit else None,
            utility=str(bandit.get("utility", "value")) if bandit else "value",
            settings=summary.get("settings") or {},
            diverged=diverged_of(summary),
            grid=os.path.realpath(run_dir) in self.grid_runs,
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
            run.label = algorithm_prefix(run.benchmark, name) + name + variant + setting
            run.narrowed = bool(run.search_space) and run.search_space != widest[run.benchmark]
            if run.narrowed:
                run.label += " on " + ", ".join(f"{k}={'/'.join(map(str, v))}" for k, v in run.search_space.items())


NOT_SETTINGS = ("seed", "env_id", "run_name", "exp_name", "runs_dir", "resume", "init_from", "quiet",
                "total_timesteps", "track", "wandb_project_name", "wandb_entity", "wandb_group", "capture_video",
                "video_every", "evaluate")
"""Fields of a run's settings that say which run it is or what it records, not how it learns: never named in a
method's label."""


def disagreeing_settings(runs: list[Run], defaults: dict | None = None) -> list[str]:
    """The settings on which fixed-settings runs disagree, in the order of their runs' settings; a setting a run
    does not record counts as ``defaults[key]`` (None without defaults)."""
    defaults = defaults or {}
    keys = dict.fromkeys(key for run in runs for key in run.settings if key not in NOT_SETTINGS)
    disagreeing = []
    for key in keys:  # one pass over the runs per setting: the report labels hundreds of fixed runs with this
        values = [run.settings.get(key, defaults.get(key)) for run in runs]
        if any(value != values[0] for value in values):
            disagreeing.append(key)
    return disagreeing


def fixed_settings_text(run: Run, runs: list[Run]) -> str:
    """", update_epochs=5" for a fixed-settings run whose settings differ from its script's defaults, naming only
    the settings on which the benchmark's fixed-settings runs disagree (so one set of runs keeps the plain name); a
    grid's runs are named among themselves, the others among the others."""
    peers = [r for r in runs if r.kind == run.kind and r.benchmark == run.benchmark and r.grid == run.grid]
    defaults = script_defaults(run.benchmark)
    disagreeing = disagreeing_settings(peers, defaults)
    named = [f"{key}={value}" for key, value in run.settings.items()
             if key in disagreeing and key in defaults and value != defaults[key]]
    return (", " + ", ".join(named)) if named else ""


_DEFAULTS: dict[str, dict] = {}


def script_defaults(benchmark: str) -> dict:
    """The literal defaults of a benchmark's script's Args dataclass, read from its source in the checkout
    (empty when the script is not there)."""
    if benchmark not in _DEFAULTS:
        stem = "sac_ultho_dmc" if benchmark == "dmc" else f"ppo_ultho_{benchmark}"
        path = os.path.join(CHECKOUT, f"{stem}.py")
        _DEFAULTS[benchmark] = script_literals(path)[1] if os.path.exists(path) else {}
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


def diverged_of(summary: dict) -> dict | None:
    """Where a run stopped because its loss became non-finite (summary.json's ``diverged``: what, iteration,
    global_step), or None: the key is null in a run that did not diverge and absent in summaries written before
    the scripts recorded it. Such a run is finished: it is scored with the final score it had reached."""
    diverged = summary.get("diverged")
    if diverged is None:
        return None
    return {"what": str(diverged["what"]), "iteration": int(diverged["iteration"]),
            "global_step": int(diverged["global_step"])}


def curve_budget_of(summary: dict) -> int:
    """The steps a run's curve counts as its whole budget in the sample-efficiency tables: those it trained, or
    for a run that diverged its ``--total-timesteps``, so that a run that stopped early without reaching the
    threshold is not counted as if it had used fewer steps than its peers."""
    steps = int(summary["global_step"])
    if diverged_of(summary) is None:
        return steps
    return max(steps, int((summary.get("settings") or {}).get("total_timesteps") or 0))


def baseline_of(benchmark: str) -> str:
    """The name of a benchmark's fixed-settings runs (the script with --no-ultho)."""
    return "SAC" if benchmark == "dmc" else "PPO"


def algorithm_prefix(benchmark: str, name: str) -> str:
    """"SAC + " before ULTHO's methods where the algorithm it tunes is not PPO (DMC), so that a label names it:
    "SAC + ULTHO (c=5, W=10)"; on the PPO benchmarks ULTHO is PPO's and the label stays "ULTHO (c=5, W=10)"."""
    baseline = baseline_of(benchmark)
    return "" if baseline == "PPO" else f"{baseline} + "


def fixed_settings(runs: list[Run], benchmark: str) -> dict:
    """The settings of the benchmark's fixed-settings runs, those labelled by ``baseline_of`` alone: each setting
    they all share, else (or without such runs) the script's default. The figures mark these values as the
    baseline's own beside the values ULTHO chose."""
    settings = dict(script_defaults(benchmark))
    plain = [r for r in runs if r.kind == "ppo" and r.benchmark == benchmark and r.label == baseline_of(benchmark)]
    for key in set().union(*(r.settings for r in plain)):
        values = [r.settings.get(key) for r in plain]
        if all(value == values[0] for value in values):
            settings[key] = values[0]
    return settings


def method_order(runs: list[Run]) -> list[str]:
    """The methods' labels in the order of every table and legend: the baseline, ULTHO (the paper's bandit
    first, then by c and W), Relay-ULTHO, then the HPO studies."""
    rank = {"ppo": 0, "ultho": 1, "relay": 2, "pbt": 3, "pb2": 4, "random": 5}
    keyed = {run.label: (rank[run.kind], run.variant != PAPER_VARIANT, run.variant, run.c or 0, run.window or 0,
                         run.label) for run in runs}
    return sorted(keyed, key=keyed.get)

"""The paper's HPO baselines — PBT, PB2 and random search — on the same PPO as ULTHO, through Ray Tune.

Every trial is the benchmark's own script with ``--no-ultho`` and the trial's settings: the same network, PPO
and defaults as the PPO and ULTHO runs. The search space is the script's ULTHO space (``--ultho-clusters``
after ``--``, the paper's Table 2 by default), so every method searches what ULTHO searches:

- ``pbt``: population-based training (Jaderberg et al. 2017) with Ray Tune's ``PopulationBasedTraining``,
  synchronous: at every ``--interval`` steps all trials stop, the bottom quarter copies the state of a trial
  from the top quarter (network, optimizer, normalization statistics, environments, counters) and explores
  from its settings, each cluster resampled from its values or moved to a neighbouring value;
- ``pb2``: population-based bandits (Parker-Holder et al. 2020) with Tune's ``PB2``, the same exploit, but
  explore picks new settings with a Gaussian-process bandit over the numeric range each cluster spans
  (integers rounded, minibatch sizes to the nearest divisor of the rollout in that range);
- ``random``: random search, ``--samples`` trials with one setting each, drawn from the clusters' values.

A trial runs in segments of ``--interval`` steps, each one process of the script that starts from the
previous segment's checkpoint (``--init-from``, in place) and reports its score (the mean return of the last
100 training episodes) and checkpoint to Tune; an exploit starts the next segment from the other trial's
checkpoint instead, with the new settings. Each trial has one run directory, ``<study>/trials/trial_<k>``,
whose TensorBoard ``hparams/*`` show the schedule it followed; ``<study>/study.json`` records the method, the
budget, every exploit, the best trial and its settings schedule (docs/hpo_baselines.md has the format).

Killed and started again with the same arguments, a study continues from Tune's experiment state: finished
trials are not run again, running ones restart from their last reported checkpoint (at most one interval
lost). Locally a Ray instance is started for the study; ``--ray-address`` uses an existing cluster.

With ``--track`` every trial is a Weights & Biases run (its segments go on in the same W&B run), all trials of the
study in one W&B group: the study directory's name unless ``--wandb-group`` says otherwise (Tune's experiment in
it is always called ``tune``; sweep.py gives its own group, so that a sweep is one group).
"""

import argparse
import contextlib
import ctypes
import hashlib
import importlib.util
import io
import json
import logging
import math
import os
import random
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from dataclasses import dataclass
from typing import Optional

from ultho_bandit import format_value
from ultho_runs import (UsageError, add_tracking_options, atomic_write_json, check_script_args, flag_values,
                        parse_split_args, print_error, read_json, relative_to, resolve_script, tracking_flags,
                        without_flag)

TOOL = "hpo_baselines.py"
STUDY_FORMAT = 1
METHODS = ("pbt", "pb2", "random")
OWNED_FLAGS = ("--seed",)
"""Script flags the tool sets per trial, on top of ultho_runs.OWNED_FLAGS (--no-ultho, --run-name, --runs-dir,
--resume, --init-from)."""
SCORE = "score"
TRIAL_RECORD = "hpo_trial.json"
CHECKPOINT_RECORD = "hpo_checkpoint.json"


@dataclass(frozen=True)
class Plan:
    """Everything a trial needs to run its segments; the same for every trial of a study."""
    method: str
    script: str
    script_args: tuple[str, ...]
    """the user's arguments after --, less those each segment sets (the clusters' settings, --ultho-clusters,
    --total-timesteps, --eval-episodes)"""
    study_dir: str
    seed: int
    space: dict
    """the searched clusters: name -> values (each with at least two)"""
    fixed: dict
    """clusters with a single value: set in every trial, never searched"""
    batch_size: int
    final_step: int
    """the steps every trial runs: --total-timesteps rounded down to whole iterations, as the script does"""
    interval: int
    eval_episodes: Optional[int]
    """the user's --eval-episodes, for the final segment (earlier ones evaluate nothing)"""
    tracking: tuple[str, ...] = ()
    """the W&B flags of --track, for every segment (none without it)"""

    @property
    def trials_dir(self) -> str:
        return os.path.join(self.study_dir, "trials")

    def settings_of(self, config: dict) -> dict:
        """The script settings of a Tune config. PB2 proposes real numbers in each cluster's range: integer
        clusters are rounded, minibatch sizes go to the nearest divisor of the rollout within the range."""
        settings = dict(self.fixed)
        for name, values in self.space.items():
            value = config[name]
            if all(isinstance(v, int) for v in values):
                low, high = min(values), max(values)
                candidates = range(low, high + 1)
                if name == "minibatch_size":
                    candidates = [m for m in candidates if self.batch_size % m == 0]
                value = min(candidates, key=lambda c: (abs(c - value), c))
            else:
                value = float(value)
            settings[name] = value
        return settings

    def segment_command(self, name: str, seed: int, end_step: int, settings: dict,
                        init_from: Optional[str]) -> list[str]:
        flags = [token for setting, value in settings.items()
                 for token in (f"--{setting.replace('_', '-')}", format_value(value))]
        # Only the last segment evaluates the policy (--eval-episodes after --, else the script's default).
        evaluation = ["--eval-episodes", str(self.eval_episodes)] if self.eval_episodes is not None else []
        if end_step < self.final_step:
            evaluation = ["--eval-episodes", "0"]
        start = ["--init-from", init_from] if init_from is not None else []
        return [sys.executable, self.script, *self.script_args, *flags, "--no-ultho", "--seed", str(seed),
                "--total-timesteps", str(end_step), *evaluation, *start, "--runs-dir", self.trials_dir,
                "--run-name", name, "--quiet", *self.tracking]


def trial_index(trial_id: str) -> int:
    """Tune's trial ids end in the trial's number in the study, ``<experiment>_00003``."""
    return int(trial_id.rsplit("_", 1)[1])


def trial_seed(study_seed: int, index: int) -> int:
    """Every trial its own seed (network initialization, environments, sampling), fixed by the study's."""
    return study_seed * 1000 + index


def die_with_parent() -> None:
    """The script dies with the trial that started it (Linux), so a killed study leaves no segment running."""
    try:
        ctypes.CDLL("libc.so.6").prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def run_trial(config: dict, plan: Plan) -> None:
    """Tune's function trainable: the trial's segments, from its last reported checkpoint (its own or, after an
    exploit, another trial's) to the end of the budget."""
    from ray import tune

    index = trial_index(tune.get_context().get_trial_id())
    name, seed = f"trial_{index}", trial_seed(plan.seed, index)
    run_dir = os.path.join(plan.trials_dir, name)
    record_path = os.path.join(run_dir, TRIAL_RECORD)
    settings = plan.settings_of(config)
    record = read_json(record_path) if os.path.isfile(record_path) else None
    checkpoint = tune.get_checkpoint()
    if record is not None and record["complete"]:
        # Tune lost the news that this trial finished (killed right after it): report it again, run nothing.
        tune.report(metrics(record["segments"][-1], record, plan.final_step))
        return
    start_step, init_from, origin = 0, None, None
    if checkpoint is not None:
        scratch = os.path.join(plan.study_dir, "tmp")
        os.makedirs(scratch, exist_ok=True)
        init_from = checkpoint.to_directory(tempfile.mkdtemp(prefix=f"{name}-", dir=scratch))
        origin = read_json(os.path.join(init_from, CHECKPOINT_RECORD))
        start_step = origin["step"]
    elif os.path.exists(run_dir):
        shutil.rmtree(run_dir)  # killed before its first report: nothing in it is Tune's, start afresh
    if record is None or checkpoint is None:
        record = {"name": name, "seed": seed, "complete": False, "segments": []}
    # Segments past the checkpoint are run again (a restart after a kill, or an exploit of a trial behind).
    record["segments"] = [s for s in record["segments"] if s["end_step"] <= start_step]
    record["diverged"] = next((s["diverged"] for s in record["segments"] if s.get("diverged")), None)
    os.makedirs(os.path.join(plan.study_dir, "logs"), exist_ok=True)
    while start_step < plan.final_step:
        end_step = min(start_step + plan.interval, plan.final_step)
        # A trial that has diverged trains no more, yet reports at every interval to the end of the budget: a
        # synchronous PBT or PB2 waits at each perturbation for every trial still running, and one that ended
        # early would leave the others waiting for it for good.
        if record["diverged"] is None:
            command = plan.segment_command(name, seed, end_step, settings, init_from)
            tick = time.time()
            with open(os.path.join(plan.study_dir, "logs", f"{name}.log"), "a") as log:
                log.write(f"[{TOOL}] {' '.join(command[1:])}\n")
                log.flush()
                status = subprocess.run(command, stdout=log, stderr=log, preexec_fn=die_with_parent).returncode
            summary = read_json(os.path.join(run_dir, "summary.json"))
            # Exit status 1 with a summary that records a divergence ends the trial's training: a retry would
            # replay the same divergence. (The script removes an earlier segment's summary when it starts.)
            diverged = summary.get("diverged") if status == 1 and summary is not None else None
            if status != 0 and diverged is None:
                raise RuntimeError(f"{name}: {os.path.basename(plan.script)} exited with status {status} in the "
                                   f"segment to step {end_step} (log: "
                                   f"{os.path.join(plan.study_dir, 'logs', name + '.log')})")
            record["segments"].append({
                "start_step": start_step, "end_step": end_step, "settings": settings,
                "started_from": None if origin is None else {"trial": origin["trial"], "step": origin["step"],
                                                             "settings": origin["settings"]},
                "score": summary["final_score"], "diverged": diverged, "wall_time_s": time.time() - tick})
            record["diverged"] = diverged
        if init_from is not None and init_from != run_dir:
            shutil.rmtree(init_from, ignore_errors=True)
        record["complete"] = end_step == plan.final_step
        atomic_write_json(record_path, record)
        with tempfile.TemporaryDirectory(dir=plan.study_dir) as staging:
            if record["diverged"] is None:  # a diverged trial's checkpoint only says where it is: no one copies it
                shutil.copy(os.path.join(run_dir, "checkpoint.pt"), staging)
            atomic_write_json(os.path.join(staging, CHECKPOINT_RECORD),
                              {"trial": name, "step": end_step, "settings": settings})
            tune.report(metrics(record["segments"][-1], record, end_step),
                        checkpoint=tune.Checkpoint.from_directory(staging))
        start_step, init_from, origin = end_step, run_dir, {"trial": name, "step": end_step, "settings": settings}


def metrics(segment: dict, record: dict, global_step: int) -> dict:
    """What a trial reports to Tune at ``global_step``. Before its first episode has ended a trial has no score,
    and once it has diverged its network is not finite: NaN, which Tune's PBT leaves out of the ranking (the trial
    neither copies nor is copied) while the population stays in step; a missing metric instead would let the
    trial run ahead of a synchronous population and stall it. study.json keeps a diverged trial's last score."""
    unscored = segment["score"] is None or record.get("diverged") is not None
    return {"global_step": global_step, SCORE: math.nan if unscored else segment["score"],
            "steps_run": steps_run(record["segments"]), "diverged": record.get("diverged") is not None}


def steps_run(segments: list[dict]) -> int:
    """The environment steps the segments ran: a segment that diverged stopped at the step its summary names."""
    return sum((s["diverged"]["global_step"] if s.get("diverged") else s["end_step"]) - s["start_step"]
               for s in segments)


def schedulers() -> tuple[type, type]:
    """Tune's synchronous PBT and PB2, with two repairs.

    Tune sets the next synchronization point to max(last point + interval, the furthest trial). After a
    restart the scheduler is new (its first point is one interval) while the trials are further on, so that
    point equals the step the population has reached and no paused trial is ever started again; here it is
    always an interval beyond the furthest trial. And PB2 keeps unscored results (NaN) out of its Gaussian
    process's data, where one NaN would stop the fit; they still count for the synchronization, as in PBT.
    """
    from ray.tune.schedulers import PopulationBasedTraining
    from ray.tune.schedulers.pb2 import PB2

    class Resynchronizing:
        def on_trial_result(self, tune_controller, trial, result):
            point = self._next_perturbation_sync
            decision = super().on_trial_result(tune_controller, trial, result)
            if self._next_perturbation_sync != point:  # the population has just been synchronized
                furthest = max(state.last_train_time for state in self._trial_state.values())
                self._next_perturbation_sync = max(self._next_perturbation_sync,
                                                   furthest + self._perturbation_interval)
            return decision

    class PBTStudy(Resynchronizing, PopulationBasedTraining):
        pass

    class PB2Study(Resynchronizing, PB2):
        def _save_trial_state(self, state, time, result, trial):
            if math.isnan(result[SCORE]):
                return PopulationBasedTraining._save_trial_state(self, state, time, result, trial)
            return super()._save_trial_state(state, time, result, trial)

    return PBTStudy, PB2Study


def lineage(trials: dict[str, dict], name: str, until: Optional[int] = None) -> list[dict]:
    """The settings schedule behind a trial's network at step ``until`` (default: its end): its own segments,
    and before an exploit the segments of the trial it copied, back to step 0."""
    schedule: list[dict] = []
    segments = [s for s in trials[name]["segments"] if until is None or s["end_step"] <= until]
    for segment in reversed(segments):
        schedule.insert(0, {"start_step": segment["start_step"], "end_step": segment["end_step"], "trial": name,
                            "settings": segment["settings"]})
        source = segment["started_from"]
        if source is not None and source["trial"] != name:
            return lineage(trials, source["trial"], source["step"]) + schedule
    return schedule


def study_record(plan: Plan, arguments: dict, status: str) -> dict:
    """study.json, rebuilt from the trials' own records (so it is right after any restart)."""
    trials = {}
    for entry in sorted(os.listdir(plan.trials_dir) if os.path.isdir(plan.trials_dir) else [],
                        key=lambda n: int(n.split("_")[1]) if n.startswith("trial_") else -1):
        record = read_json(os.path.join(plan.trials_dir, entry, TRIAL_RECORD))
        if record is not None:
            trials[entry] = record
    exploits, observed = [], []
    for name, record in trials.items():
        previous = None
        for segment in record["segments"]:
            source = segment["started_from"]
            if source is not None and source["trial"] != name:
                exploits.append({"step": source["step"], "trial": name, "source_trial": source["trial"],
                                 "old_settings": previous["settings"] if previous else None,
                                 "source_settings": source["settings"], "new_settings": segment["settings"]})
            if segment["score"] is not None:
                observed.append({"score": segment["score"], "trial": name, "step": segment["end_step"]})
            previous = segment
    exploits.sort(key=lambda e: (e["step"], int(e["trial"].split("_")[1])))
    # A diverged trial keeps its last score in its entry, but its network is not finite: it is never the best.
    finished = {n: r for n, r in trials.items() if r["complete"] and r.get("diverged") is None}
    scored = {n: r["segments"][-1]["score"] for n, r in finished.items() if r["segments"][-1]["score"] is not None}
    best = max(scored, key=lambda n: (scored[n], -int(n.split("_")[1]))) if scored else None
    return {
        "format": STUDY_FORMAT, "tool": TOOL, "status": status, "method": plan.method, **arguments,
        "search_space": plan.space, "fixed_settings": plan.fixed,
        "budget": {"steps_per_trial": plan.final_step, "trials": arguments["population"] or arguments["samples"],
                   "total_steps": sum(steps_run(r["segments"]) for r in trials.values()),
                   "interval": plan.interval},
        "best_trial": best,
        "best_final_score": scored[best] if best else None,
        "best_settings_schedule": lineage(trials, best) if best else None,
        "max_observed_score": max(observed, key=lambda o: o["score"]) if observed else None,
        "exploits": exploits,
        "trials": [{"name": n, "seed": r["seed"],
                    "run_dir": relative_to(os.path.join(plan.trials_dir, n), plan.study_dir),
                    "complete": r["complete"], "diverged": r.get("diverged"),
                    "settings": r["segments"][-1]["settings"] if r["segments"] else None,
                    "final_score": r["segments"][-1]["score"] if r["complete"] else None,
                    "steps_run": steps_run(r["segments"]),
                    "segments": r["segments"]} for n, r in trials.items()],
    }


def load_script(path: str):
    """The script as a module, for its search space and its own argument checks (nothing runs on import)."""
    spec = importlib.util.spec_from_file_location(os.path.splitext(os.path.basename(path))[0] + "_checked", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def checked_plan(args: argparse.Namespace, script_args: list[str], study_dir: str) -> Plan:
    """The study's plan, every input checked by the tool and by the script itself; nothing is started."""
    if args.method not in METHODS:
        raise UsageError(f"--method {args.method}: not one of {', '.join(METHODS)}")
    if args.method == "random":
        if args.population is not None:
            raise UsageError("--population is for pbt and pb2; random search takes --samples")
        if args.samples is None or args.samples < 1:
            raise UsageError(f"--samples must be >= 1 for random search, got {args.samples}")
    else:
        if args.samples is not None:
            raise UsageError(f"--samples is for random search; {args.method} takes --population")
        if args.population is None or args.population < 2:
            raise UsageError(f"--population must be >= 2 for {args.method} (a trial exploits another), "
                             f"got {args.population}")
    if args.max_retries < 0 or args.cpus_per_trial <= 0 or args.gpus_per_trial < 0:
        raise UsageError("--max-retries and --gpus-per-trial must be >= 0, --cpus-per-trial positive")
    if args.num_cpus is not None and (args.ray_address or args.num_cpus < 1):
        raise UsageError(f"--num-cpus {args.num_cpus}: it sizes the local Ray instance (at least 1); a cluster "
                         "at --ray-address has its own" if args.ray_address else f"--num-cpus must be >= 1, got "
                         f"{args.num_cpus}")
    if not 0 < args.quantile <= 0.5:
        raise UsageError(f"--quantile must be in (0, 0.5], got {args.quantile}")
    if not 0 <= args.resample_probability <= 1:
        raise UsageError(f"--resample-probability must be in [0, 1], got {args.resample_probability}")
    try:
        check_script_args(script_args)
    except UsageError as err:
        raise UsageError(str(err).replace("the tool itself", f"{TOOL} for every trial")) from None
    for token in script_args:
        for flag in OWNED_FLAGS:
            if token == flag or token.startswith(flag + "="):
                raise UsageError(f"{flag} is set by {TOOL} for every trial (--seed before -- is the study's seed); "
                                 "remove it from the arguments after --")
    tracking = tracking_flags(args, script_args, os.path.basename(study_dir))
    script = resolve_script(args.script)
    module = load_script(script)
    stem = module.SCRIPT
    try:  # the script's own checks, every candidate value of the search space included
        # A runs directory that does not exist: the script's check that its run directory is new must pass.
        parsed = module.parse_args([*script_args, "--runs-dir", os.path.join(study_dir, "tmp", "never-written"),
                                    "--run-name", "trial_0", *tracking])
        space, _ = module.validate(parsed)
    except module.UsageError as err:
        raise UsageError(f"{stem}: {err}") from None
    batch_size = parsed.num_envs * parsed.num_steps
    final_step = parsed.total_timesteps // batch_size * batch_size
    iterations = final_step // batch_size
    interval = args.interval if args.interval is not None else math.ceil(iterations / 10) * batch_size
    if interval <= 0 or interval % batch_size:
        made_of = (f"--ultho-interval {parsed.ultho_interval}" if hasattr(parsed, "ultho_interval")
                   else f"--num-envs {parsed.num_envs} x --num-steps {parsed.num_steps}")
        raise UsageError(f"--interval {interval} is not a whole number of iterations (one iteration is "
                         f"{batch_size} steps: {made_of})")
    searched = {name: values for name, values in space.items() if len(values) > 1}
    if not searched:
        raise UsageError(f"--ultho-clusters {' '.join(parsed.ultho_clusters)}: no cluster has two values to search")
    eval_given = flag_values(script_args, "--eval-episodes")
    passed_on = script_args  # the trial sets these itself, each segment
    for flag in ("--ultho-clusters", "--eval-episodes", "--total-timesteps",
                 *(f"--{name.replace('_', '-')}" for name in space)):
        passed_on = without_flag(passed_on, flag)
    return Plan(method=args.method, script=script, script_args=tuple(passed_on),
                study_dir=study_dir, seed=args.seed, space=searched,
                fixed={name: values[0] for name, values in space.items() if len(values) == 1},
                batch_size=batch_size, final_step=final_step, interval=interval,
                eval_episodes=int(eval_given[0]) if eval_given else None, tracking=tuple(tracking))


def default_study_dir(args: argparse.Namespace, script_args: list[str]) -> str:
    """runs/hpo__<method>__<script>__<env>__<seed>__<hash of the arguments>: the same command, the same study."""
    env = (flag_values(script_args, "--env-id") or ["default"])[0].replace("/", "-")
    key = json.dumps([os.path.basename(args.script), args.method, args.population, args.samples, args.interval,
                      args.quantile, args.resample_probability, script_args])
    stem = os.path.splitext(os.path.basename(args.script))[0]
    return os.path.join("runs", f"hpo__{args.method}__{stem}__{env}__{args.seed}__"
                                f"{hashlib.sha1(key.encode()).hexdigest()[:8]}")


def study(args: argparse.Namespace, script_args: list[str], log=print) -> dict:
    """Runs (or continues) the study to the end and returns study.json."""
    study_dir = os.path.abspath(args.study_dir or default_study_dir(args, script_args))
    plan = checked_plan(args, script_args, study_dir)
    arguments = {"script": os.path.basename(args.script), "script_args": script_args, "seed": args.seed,
                 "population": args.population, "samples": args.samples,
                 "interval": args.interval, "quantile": args.quantile,
                 "resample_probability": args.resample_probability}
    study_path = os.path.join(study_dir, "study.json")
    existing = read_json(study_path) if os.path.isfile(study_path) else None
    given = {**arguments, "method": args.method}
    if existing is not None and {k: existing.get(k) for k in given} != given:
        raise UsageError(f"{study_dir} holds a study of other arguments: {existing['method']} of {existing['script']} "
                         f"{' '.join(existing['script_args'])}")
    if existing is not None and existing["status"] == "done":
        log(f"[hpo] {study_path} is done; nothing to run")
        return existing

    if not args.ray_address:  # (read when ray is imported)
        # The local instance gets a token of its own. Left to itself, Ray would write one to ~/.ray/auth_token,
        # for good, and every later `ray start` on the machine would then demand it.
        os.environ.setdefault("RAY_AUTH_MODE", "token")
        os.environ.setdefault("RAY_AUTH_TOKEN", secrets.token_hex(32))
        # Ray starts its workers at niceness 15 so that its own services stay responsive. Here the trials are the
        # study's whole work: beside any busy process they would get a few percent of a core. They train at the
        # niceness the tool was started with, as a plain script's run does.
        os.environ.setdefault("RAY_worker_niceness", "0")
    # Tune's own TensorBoard files would look like runs to ultho_report; its JSON and CSV logs stay.
    os.environ.setdefault("TUNE_DISABLE_AUTO_CALLBACK_LOGGERS", "1")
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")
    # Tune saves its experiment state (what a restart continues from) at most once a second rather than every
    # 10 s or more: a few trials' state is small, and a kill then loses at most the running segments.
    os.environ.setdefault("TUNE_GLOBAL_CHECKPOINT_S", "1")
    import ray
    from ray import tune
    from ray.tune.logger import CSVLoggerCallback, JsonLoggerCallback
    from ray.tune.search.basic_variant import BasicVariantGenerator

    os.makedirs(study_dir, exist_ok=True)
    atomic_write_json(study_path, study_record(plan, arguments, "running"))
    random.seed(args.seed)  # PBT's explore draws from random, PB2's from numpy
    import numpy as np
    np.random.seed(args.seed)

    class StudyIndex(tune.Callback):
        """Rewrites study.json whenever a trial reports, and says so in one line."""

        def on_trial_result(self, iteration, trials, trial, result, **info):
            atomic_write_json(study_path, study_record(plan, arguments, "running"))
            score = result[SCORE]
            log(f"[hpo] trial_{trial_index(trial.trial_id)} step {result['global_step']}/{plan.final_step}: "
                + ("diverged, trains no more" if result.get("diverged") else
                   f"score {'-' if math.isnan(score) else f'{score:.4g}'}") + " with "
                + ", ".join(f"{k}={format_value(v)}" for k, v in plan.settings_of(trial.config).items()))

    warnings.filterwarnings("ignore", message="Consider boosting PBT performance")  # our trial is a process
    with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
        # "local": a Ray instance of the study's own, never one that `ray start` left running on this machine
        # (which ray.init() without an address would join, with another token and other CPUs).
        ray.init(address=args.ray_address or "local", num_cpus=None if args.ray_address else args.num_cpus,
                 include_dashboard=False, log_to_driver=False, logging_level="ERROR")
    logging.getLogger("ray").setLevel(logging.ERROR)
    try:
        trainable = tune.with_resources(tune.with_parameters(run_trial, plan=plan),
                                        {"cpu": args.cpus_per_trial, "gpu": args.gpus_per_trial})
        tune_dir = os.path.join(study_dir, "tune")
        if tune.Tuner.can_restore(tune_dir):
            log(f"[hpo] continuing the study in {study_dir}")
            tuner = tune.Tuner.restore(tune_dir, trainable=trainable, resume_unfinished=True, resume_errored=True)
        else:
            pbt_scheduler, pb2_scheduler = schedulers()
            if args.method == "pbt":
                param_space = {name: tune.choice(values) for name, values in plan.space.items()}
                scheduler = pbt_scheduler(
                    time_attr="global_step", perturbation_interval=plan.interval, hyperparam_mutations=plan.space,
                    quantile_fraction=args.quantile, resample_probability=args.resample_probability,
                    synch=True)
            elif args.method == "pb2":
                param_space = {name: tune.uniform(min(values), max(values)) for name, values in plan.space.items()}
                scheduler = pb2_scheduler(
                    time_attr="global_step", perturbation_interval=plan.interval,
                    hyperparam_bounds={name: [min(v), max(v)] for name, v in plan.space.items()},
                    quantile_fraction=args.quantile, synch=True)
            else:
                param_space = {name: tune.choice(values) for name, values in plan.space.items()}
                scheduler = None
            tuner = tune.Tuner(
                trainable, param_space=param_space,
                tune_config=tune.TuneConfig(metric=SCORE, mode="max", scheduler=scheduler,
                                            num_samples=args.population or args.samples,
                                            search_alg=BasicVariantGenerator(random_state=args.seed),
                                            reuse_actors=False),
                run_config=tune.RunConfig(
                    name="tune", storage_path=study_dir, verbose=0, log_to_file=True,
                    stop={"global_step": plan.final_step},  # ends a trial at its last report, without a pause
                    callbacks=[JsonLoggerCallback(), CSVLoggerCallback(), StudyIndex()],
                    checkpoint_config=tune.CheckpointConfig(num_to_keep=args.keep_checkpoints or None),
                    failure_config=tune.FailureConfig(max_failures=args.max_retries)))
        results = tuner.fit()
    finally:
        ray.shutdown()
    errors = [str(r.error).strip().splitlines()[-1] for r in results if r.error is not None]
    record = study_record(plan, arguments, "failed" if errors else "done")
    record["errors"] = errors
    atomic_write_json(study_path, record)
    if errors:
        raise StudyFailed(f"{len(errors)} trial(s) failed: {errors[0]}")
    best = record["best_trial"]
    log(f"[hpo] done: {len(record['trials'])} trials, {record['budget']['total_steps']:,} steps in all, "
        f"{len(record['exploits'])} exploits; best trial {best} with final score "
        f"{record['best_final_score']}; {study_path}")
    return record


class StudyFailed(Exception):
    """A trial that failed within its retries; the same command continues the study."""


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    parser = argparse.ArgumentParser(
        prog=TOOL,
        usage=f"{TOOL} [-h] --method {{pbt,pb2,random}} [--population N | --samples N] [options] SCRIPT "
              "[-- SCRIPT_ARGS...]",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="The paper's HPO baselines on the same PPO as ULTHO, through Ray Tune: population-based "
                    "training (pbt), population-based bandits (pb2) and random search (random). Every trial is "
                    "SCRIPT with --no-ultho and the trial's settings, searching the script's ULTHO space "
                    "(--ultho-clusters after --, the paper's by default); every trial runs the script's "
                    "--total-timesteps, so a study costs population x that many steps. Writes the trials' run "
                    "directories and study.json into the study directory. Run the same command again after a "
                    "crash: finished trials are kept, running ones restart from their last checkpoint.",
        epilog="examples:\n"
               "  python hpo_baselines.py ppo_ultho_minigrid.py --method pbt --population 4 --seed 1 -- "
               "--env-id MiniGrid-DoorKey-6x6-v0\n"
               "  python hpo_baselines.py ppo_ultho_procgen.py --method pb2 --population 4 --ray-address HOST:6379 "
               "-- --env-id coinrun\n"
               "  python hpo_baselines.py ppo_ultho_atari.py --method random --samples 8 -- --env-id Qbert\n"
               "\nThe tool sets the script's --seed (trial k: SEED*1000+k), --init-from, --run-name, --runs-dir "
               "and --no-ultho itself; --track and --wandb-* go before --, to the tool, which passes them on."
               "\nFormats and every choice: docs/hpo_baselines.md.",
    )
    parser.add_argument("script", help="the training script, e.g. ppo_ultho_minigrid.py")
    parser.add_argument("--method", required=True, metavar="{pbt,pb2,random}",
                        help="pbt (Tune's PopulationBasedTraining), pb2 (Tune's PB2) or random (random search)")
    parser.add_argument("--population", type=int, metavar="N", help="trials of pbt and pb2 (at least 2)")
    parser.add_argument("--samples", type=int, metavar="N", help="trials of random search, one setting each")
    parser.add_argument("--seed", type=int, default=1, help="the study's seed: trial k runs the script with --seed "
                        "SEED*1000+k, and Tune's sampling and exploration draw from it (default 1)")
    parser.add_argument("--interval", type=int, metavar="STEPS",
                        help="steps between perturbations (pbt, pb2) and between a trial's checkpoints, a whole "
                             "number of iterations (default: a tenth of the budget, rounded up to iterations)")
    parser.add_argument("--quantile", type=float, default=0.25, metavar="Q",
                        help="pbt, pb2: the bottom Q of the population copies the top Q (default 0.25)")
    parser.add_argument("--resample-probability", type=float, default=0.25, metavar="P",
                        help="pbt: chance that explore resamples a cluster instead of moving to a neighbouring "
                             "value (default 0.25)")
    parser.add_argument("--study-dir", metavar="DIR", help="where the trials, logs and study.json go (default: "
                        "runs/hpo__<method>__<script>__<env>__<seed>__<hash of the arguments>)")
    parser.add_argument("--ray-address", metavar="ADDR",
                        help="run the trials on this running Ray cluster (default: a local Ray instance)")
    parser.add_argument("--num-cpus", type=int, metavar="N",
                        help="CPUs of the local Ray instance (default: the machine's)")
    parser.add_argument("--cpus-per-trial", type=float, default=1, metavar="N",
                        help="CPUs a trial reserves (default 1)")
    parser.add_argument("--gpus-per-trial", type=float, default=0, metavar="N",
                        help="GPUs a trial reserves, fractions allowed (default 0)")
    parser.add_argument("--keep-checkpoints", type=int, default=3, metavar="N",
                        help="Tune checkpoints kept per trial, the newest (default 3, the fewest Tune advises for "
                             "PBT; 0 keeps all)")
    parser.add_argument("--max-retries", type=int, default=2, metavar="N",
                        help="times a failed trial restarts from its last checkpoint (default 2)")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    add_tracking_options(parser, "every trial (one W&B run each, across its segments)",
                         "the study directory's name")
    return parse_split_args(parser, argv)


def main(argv: list[str]) -> int:
    try:
        args, script_args = parse_args(argv)
        if args.keep_checkpoints < 0:
            raise UsageError(f"--keep-checkpoints must be >= 0, got {args.keep_checkpoints}")
        study(args, script_args, log=(lambda line: None) if args.quiet else (lambda line: print(line, flush=True)))
    except UsageError as err:
        print_error(TOOL, err)
        return 2
    except StudyFailed as err:
        print_error(TOOL, f"{err}; run the same command again to continue the study")
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

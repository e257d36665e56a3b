"""The paper's experiment grids, from one machine to a Ray cluster.

A grid (scripts x environment ids x methods x seeds, with every (c, W) for ULTHO) expands into runs, each
a deterministic directory under ``<out>/runs`` (a relay: ``<out>/relays``; a PBT, PB2 or random-search study
of ``hpo_baselines.py``: ``<out>/studies``), so the same command always
names the same runs. Started again, a sweep skips every run that has its ``summary.json`` (a relay: its
``relay.json`` with status done), resumes interrupted or failed runs from their checkpoints with a bounded
number of retries, and starts afresh only what never checkpointed. ``--done-from DIR`` also counts as done
every run whose compact copy (``ultho_report.py --export-data DIR``, e.g. committed results) is in DIR: it is
restored from there, so a fresh clone on a new machine reruns only what had not been exported.
``<out>/sweep.json`` maps every run to its grid point and status; ``<out>/logs/<run>.log`` holds each run's output.

Runs go to local processes (``--workers`` at a time) or, with ``--ray-address``, as tasks to an existing Ray
cluster, which places them on its nodes by the resources each asks for. With ``--track`` every run is mirrored to
Weights & Biases, in one W&B group named after the sweep directory (a relay's and a study's runs included).
"""

import argparse
import concurrent.futures
import contextlib
import io
import itertools
import math
import os
import shutil
import subprocess
import sys
import dataclasses
from dataclasses import dataclass, field
from typing import Optional

from ultho_bandit import CREDITS, SCALES, STRATEGIES, format_value, parse_clusters
from ultho_runs import (RunFailed, UsageError, add_tracking_options, atomic_write_json, complete_run, parse_split_args,
                        print_error, read_json, resolve_script, run_state, script_command, script_literals,
                        tracking_flags)

TOOL = "sweep.py"
SWEEP_FORMAT = 1
RELAY_TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "relay_ultho.py")
HPO_TOOL = os.path.join(os.path.dirname(os.path.abspath(__file__)), "hpo_baselines.py")
METHODS = ("ppo", "ultho", "relay", "grid", "pbt", "pb2", "random")
HPO_METHODS = ("pbt", "pb2", "random")
"""Studies of hpo_baselines.py: --population trials of the budget each."""
PAPER_VARIANT = ("ucb", "level", "none")
"""(strategy, credit, scale): the paper's bandit; other variants add --ultho-strategy/credit/scale to their runs"""


@dataclass(frozen=True)
class Preset:
    script: str
    env_ids: tuple[str, ...]
    total_timesteps: int
    """the paper's budget per run (docs/paper.md, Table 3)"""
    measured_sps: float
    """single-run steps per second, ULTHO on, for the compute estimate: the Speed sections of docs/minigrid.md
    and docs/pybullet.md (a 2-core CPU) and docs/performance.md#gpu (one H100, for ALE and Procgen)"""


PROCGEN_GAMES = ("bigfish", "bossfight", "caveflyer", "chaser", "climber", "coinrun", "dodgeball", "fruitbot",
                 "heist", "jumper", "leaper", "maze", "miner", "ninja", "plunder", "starpilot")
PRESETS = {
    "procgen": Preset("ppo_ultho_procgen.py", PROCGEN_GAMES, 25_000_000, 6_579),
    "atari": Preset("ppo_ultho_atari.py", ("BattleZone", "DoubleDunk", "NameThisGame", "Phoenix", "Qbert"),
                    10_000_000, 1_827),
    "minigrid": Preset("ppo_ultho_minigrid.py", ("MiniGrid-DoorKey-6x6-v0", "MiniGrid-LavaGapS7-v0",
                                                 "MiniGrid-Empty-16x16-v0"), 500_000, 4_517),
    "pybullet": Preset("ppo_ultho_pybullet.py", ("AntBulletEnv-v0", "HalfCheetahBulletEnv-v0", "HopperBulletEnv-v0",
                                                 "Walker2DBulletEnv-v0"), 2_000_000, 682),
    # The paper names neither its SAC experiment's two DMC tasks nor its budget: these are this project's
    # (docs/dmc.md); steps/s measured while learning, on a 2-core CPU that another experiment kept busy.
    "dmc": Preset("sac_ultho_dmc.py", ("cheetah-run", "walker-walk"), 500_000, 110),
}
PAPER_C = (1.0, 5.0)
PAPER_WINDOWS = (10, 50, 100)
PAPER_SEEDS = (1, 2, 3, 4, 5)


@dataclass
class Run:
    """One grid point and how to bring it to done."""
    name: str
    script: str
    env_id: str
    method: str
    c: Optional[float]
    window: Optional[int]
    seed: int
    path: str
    """the run directory (a relay: the relay directory)"""
    args: list[str]
    """the script's arguments (a relay or a study: those after --)"""
    tool_args: list[str] = field(default_factory=list)
    """a study's options for hpo_baselines.py (method, population, seed, where Ray is), and a relay's or a study's
    W&B flags (--track), which its tool passes on to each run it starts"""
    source: Optional["Run"] = None
    """a relay's full ULTHO run, reused with --from when the grid has it"""
    variant: Optional[str] = None
    """the bandit's strategy:credit:scale (ultho and relay runs)"""
    settings: Optional[dict] = None
    """a grid run's fixed settings, {name: value}"""
    status: str = "pending"
    attempts: int = 0
    error: Optional[str] = None
    dependents: list["Run"] = field(default_factory=list)

    @property
    def benchmark(self) -> str:
        stem = os.path.splitext(os.path.basename(self.script))[0]
        return stem.removeprefix("ppo_ultho_")

    def is_done(self) -> bool:
        if self.method in ("relay", *HPO_METHODS):
            record = read_json(os.path.join(self.path, "relay.json" if self.method == "relay" else "study.json"))
            return record is not None and record["status"] == "done"
        return run_state(self.path) == "done"

    def relay_command(self, max_retries: int) -> list[str]:
        source = ["--from", self.source.path] if self.source is not None else []
        return [sys.executable, RELAY_TOOL, self.script, *source, "--relay-dir", self.path,
                "--max-retries", str(max_retries), "--quiet", *self.tool_args, "--", *self.args]

    def study_command(self) -> list[str]:
        return [sys.executable, HPO_TOOL, self.script, *self.tool_args, "--study-dir", self.path, "--quiet", "--",
                *self.args]

    def command(self) -> list[str]:
        """What runs first (dry run); retries use --resume."""
        if self.method == "relay":
            return self.relay_command(0)
        if self.method in HPO_METHODS:
            return self.study_command()
        return script_command(self.script, self.args, self.path, resume=False)


def fixed_settings_grid(script: str, items: Optional[list[str]]) -> list[dict]:
    """Every combination of the clusters' values, in their order (the first cluster varies slowest): the script's
    own search space by default, else the ``--grid-clusters`` items (NAME takes the script's values,
    NAME=V1,V2,... sets them, as --ultho-clusters does)."""
    constants = script_literals(script)[0]
    space = constants.get("SEARCH_SPACE") or {}
    allowed = constants.get("TUNABLE") or tuple(space)
    try:
        clusters = parse_clusters(items or list(space), space, allowed=allowed)
    except ValueError as err:
        raise UsageError(f"--grid-clusters for {os.path.basename(script)}: {err}") from None
    return [dict(zip(clusters, values)) for values in itertools.product(*clusters.values())]


def setting_flags(settings: dict) -> list[str]:
    """``{"learning_rate": 0.001}`` -> ``["--learning-rate", "0.001"]``, the scripts' own flags."""
    return [token for name, value in settings.items() for token in (f"--{name.replace('_', '-')}",
                                                                     format_value(value))]


def expand(scripts: list[str], env_ids: list[str], methods: list[str], points: list[tuple[float, int]],
           seeds: list[int], total_timesteps: Optional[int], extra_args: list[str], out: str,
           variants: tuple[tuple[str, str, str], ...] = (PAPER_VARIANT,), population: int = 4,
           study_resources: tuple[str, ...] = (), grid_clusters: Optional[list[str]] = None) -> list[Run]:
    """Every grid point in a fixed order; a relay follows the ULTHO run it reuses. ``points``: the (c, W);
    ``variants``: the (strategy, credit, scale) of the bandit; ``study_resources``: where a study's Ray runs
    its trials (--ray-address or --num-cpus); ``grid_clusters``: the clusters of the grid method's fixed settings
    (default: each script's search space)."""
    runs = []
    grids = {script: fixed_settings_grid(resolve_script(script), grid_clusters) for script in scripts} \
        if "grid" in methods else {}
    budget = ["--total-timesteps", str(total_timesteps)] if total_timesteps is not None else []
    for script, env_id, seed in itertools.product(scripts, env_ids, seeds):
        stem = os.path.splitext(os.path.basename(script))[0].removeprefix("ppo_ultho_")
        base = ["--env-id", env_id, "--seed", str(seed), *budget]
        prefix = f"{stem}__{env_id.replace('/', '-')}"
        if "ppo" in methods:
            runs.append(Run(f"{prefix}__ppo__s{seed}", script, env_id, "ppo", None, None, seed,
                            os.path.join(out, "runs", f"{prefix}__ppo__s{seed}"),
                            [*base, "--no-ultho", *extra_args, "--quiet"]))
        for variant, (c, window) in itertools.product(variants, points):
            name = "" if variant == PAPER_VARIANT else "_" + "-".join(variant)
            tag = f"{name.lstrip('_')}{'_' if name else ''}c{format_value(c)}_w{window}"
            bandit = ["--ultho-c", format_value(c), "--ultho-window", str(window)]
            if variant != PAPER_VARIANT:
                bandit += ["--ultho-strategy", variant[0], "--ultho-credit", variant[1], "--ultho-scale", variant[2]]
            ultho = None
            if "ultho" in methods:
                ultho = Run(f"{prefix}__ultho_{tag}__s{seed}", script, env_id, "ultho", c, window, seed,
                            os.path.join(out, "runs", f"{prefix}__ultho_{tag}__s{seed}"),
                            [*base, *bandit, *extra_args, "--quiet"], variant=":".join(variant))
                runs.append(ultho)
            if "relay" in methods:
                relay = Run(f"{prefix}__relay_{tag}__s{seed}", script, env_id, "relay", c, window, seed,
                            os.path.join(out, "relays", f"{prefix}__relay_{tag}__s{seed}"),
                            [*base, *bandit, *extra_args], source=ultho, variant=":".join(variant))
                runs.append(relay)
                if ultho is not None:
                    ultho.dependents.append(relay)
        for settings in grids.get(script, []):
            tag = "_".join(f"{name}-{format_value(value)}" for name, value in settings.items())
            name = f"{prefix}__grid_{tag}__s{seed}"
            runs.append(Run(name, script, env_id, "grid", None, None, seed, os.path.join(out, "runs", name),
                            [*base, "--no-ultho", *setting_flags(settings), *extra_args, "--quiet"],
                            settings=settings))
        for method in (m for m in HPO_METHODS if m in methods):
            name = f"{prefix}__{method}__s{seed}"
            size = ["--samples" if method == "random" else "--population", str(population)]
            runs.append(Run(name, script, env_id, method, None, None, seed, os.path.join(out, "studies", name),
                            [*base[:2], *budget, *extra_args],
                            tool_args=["--method", method, *size, "--seed", str(seed), *study_resources]))
    return runs


def track(runs: list[Run], flags: list[str]) -> None:
    """Adds the W&B flags of --track to every run: to a script's arguments, or to the options of the relay or study
    tool, which gives them to each run it starts."""
    for run in runs:
        if run.method in ("relay", *HPO_METHODS):
            run.tool_args = [*run.tool_args, *flags]
        else:
            run.args = [*run.args, *flags]


def execute(run: Run, max_retries: int, log_path: str) -> tuple[str, int, Optional[str]]:
    """Brings one run to done in this process's machine; returns (status, processes started, error)."""
    os.makedirs(os.path.dirname(log_path), exist_ok=True)
    with open(log_path, "a") as output:
        if run.method not in ("relay", *HPO_METHODS):
            try:
                _, attempts = complete_run(resolve_script(run.script), run.args, run.path, max_retries, output)
                return "done", attempts, None
            except RunFailed as err:
                return "failed", err.attempts, f"{err} (log: {log_path})"
        # A relay or a study resumes its own runs; it is retried as a whole while it fails for reasons other
        # than input.
        command = run.relay_command(0) if run.method == "relay" else run.study_command()
        for attempt in range(1, max_retries + 2):
            output.flush()
            status = subprocess.run(command, stdout=output, stderr=output).returncode
            if status == 0:
                return "done", attempt, None
            if status == 2:
                break
        return "failed", attempt, f"{os.path.basename(command[1])} exited with status {status} (log: {log_path})"


def restore_exported(runs: list[Run], out: str, exported: str) -> list[Run]:
    """Copies every finished run's compact export (``ultho_report.py --export-data``, which keeps the sweep
    directory's base name and layout) back into the sweep, where it counts as done; returns those restored. A
    local copy that is not done (a partial or failed attempt) gives way to the finished export."""
    restored = []
    for run in runs:
        source = os.path.join(exported, os.path.basename(out), os.path.relpath(run.path, out))
        copy = dataclasses.replace(run, path=source, source=None, dependents=[])
        if run.is_done() or not copy.is_done():
            continue
        if os.path.exists(run.path):
            shutil.rmtree(run.path)
        shutil.copytree(source, run.path)
        restored.append(run)
    return restored


def index(grid: dict, runs: list[Run], out: str) -> dict:
    return {"format": SWEEP_FORMAT, "grid": grid, "runs": [{
        "name": r.name, "script": os.path.basename(r.script), "benchmark": r.benchmark, "env_id": r.env_id,
        "method": r.method, "c": r.c, "window": r.window, "variant": r.variant, "settings": r.settings, "seed": r.seed,
        "path": os.path.relpath(r.path, out),
        "status": r.status, "attempts": r.attempts, "error": r.error} for r in runs]}


class LocalExecutor:
    """Runs as local processes, ``workers`` at a time (threads only wait on the subprocesses)."""

    def __init__(self, workers: int):
        self.pool = concurrent.futures.ThreadPoolExecutor(workers)
        self.pending: dict[concurrent.futures.Future, Run] = {}

    def submit(self, run: Run, max_retries: int, log_path: str) -> None:
        self.pending[self.pool.submit(execute, run, max_retries, log_path)] = run

    def next_finished(self) -> tuple[Run, tuple]:
        future = next(concurrent.futures.as_completed(self.pending))
        return self.pending.pop(future), future.result()

    def close(self) -> None:
        self.pool.shutdown()


class RayExecutor:
    """Each run is a Ray task on whichever node has the resources free; the cluster does the placing."""

    def __init__(self, address: str, cpus: float, gpus: float, max_retries: int):
        import ray

        self.ray = ray
        with contextlib.redirect_stderr(io.StringIO()):
            ray.init(address=address, log_to_driver=False, logging_level="ERROR")
        # Ray re-runs a task whose worker or node died; the re-run resumes from the checkpoint on shared disk.
        self.task = ray.remote(num_cpus=cpus, num_gpus=gpus, max_retries=max_retries)(execute)
        self.pending: dict = {}

    def submit(self, run: Run, max_retries: int, log_path: str) -> None:
        self.pending[self.task.remote(run, max_retries, log_path)] = run

    def next_finished(self) -> tuple[Run, tuple]:
        [ref], _ = self.ray.wait(list(self.pending), num_returns=1)
        run = self.pending.pop(ref)
        try:
            return run, self.ray.get(ref)
        except self.ray.exceptions.RayError as err:
            return run, ("failed", run.attempts + 1, f"Ray task failed: {str(err).splitlines()[0]}")

    def close(self) -> None:
        self.ray.shutdown()


def sweep(runs: list[Run], grid: dict, out: str, executor, max_retries: int, log=print,
          done_from: Optional[str] = None) -> bool:
    """Brings every run to done or failed, rewriting sweep.json as they change; True when all are done.
    ``done_from``: a folder of exported runs that count as done (restore_exported)."""
    index_path = os.path.join(out, "sweep.json")
    if done_from is not None:
        restored = restore_exported(runs, out, done_from)
        log(f"[sweep] {len(restored)} finished runs restored from {done_from}")
    previous = {r["name"]: r for r in (read_json(index_path) or {"runs": []})["runs"]}
    for run in runs:
        run.attempts = previous.get(run.name, {}).get("attempts", 0)
        run.status = "done" if run.is_done() else "pending"
    os.makedirs(out, exist_ok=True)
    atomic_write_json(index_path, index(grid, runs, out))
    todo = [r for r in runs if r.status == "pending"]
    log(f"[sweep] {len(runs)} runs, {len(runs) - len(todo)} already done, {len(todo)} to run")

    def start(run: Run) -> None:
        run.status = "running"
        executor.submit(run, max_retries, os.path.join(out, "logs", f"{run.name}.log"))

    for run in todo:
        if run.source is None or run.source.status == "done":
            start(run)
    atomic_write_json(index_path, index(grid, runs, out))
    while executor.pending:
        run, (status, attempts, error) = executor.next_finished()
        run.status, run.attempts, run.error = status, run.attempts + attempts, error
        # A run that diverged is done (its summary records where; resuming would diverge again): say so.
        diverged = ((read_json(os.path.join(run.path, "summary.json")) or {}).get("diverged")
                    if status == "done" and run.method not in ("relay", *HPO_METHODS) else None)
        log(f"[sweep] {status}: {run.name}" + (f": {error}" if error else "")
            + (f" (diverged at step {diverged['global_step']})" if diverged else ""))
        for dependent in run.dependents:
            if dependent.status == "pending":
                if status == "done":
                    start(dependent)
                else:
                    dependent.status, dependent.error = "failed", f"its ULTHO run {run.name} failed"
        atomic_write_json(index_path, index(grid, runs, out))
    failed = [r for r in runs if r.status != "done"]
    log(f"[sweep] {len(runs) - len(failed)}/{len(runs)} done" + (f", {len(failed)} failed: run the same command "
                                                                   "again to retry them" if failed else ""))
    return not failed


def total_steps(runs: list[Run], budget_of, population: int = 4) -> int:
    """Environment steps the grid costs: a relay adds two runs when it reuses its ULTHO run, else three; a
    study runs its population (random search: its samples), each for the whole budget."""
    def runs_of(run: Run) -> int:
        if run.method == "relay":
            return 2 if run.source is not None else 3
        return population if run.method in HPO_METHODS else 1
    return sum(budget_of(r) * runs_of(r) for r in runs)


def parse_variant(text: str) -> tuple[str, str, str]:
    """``"ts:improvement:running"`` -> ("ts", "improvement", "running"), for --variants."""
    parts = tuple(text.split(":"))
    if len(parts) != 3 or parts[0] not in STRATEGIES or parts[1] not in CREDITS or parts[2] not in SCALES:
        raise argparse.ArgumentTypeError(f"{text!r} is not STRATEGY:CREDIT:SCALE with a strategy of "
                                         f"{'/'.join(STRATEGIES)}, a credit of {'/'.join(CREDITS)} and a scale of "
                                         f"{'/'.join(SCALES)}")
    return parts


def parse_point(text: str) -> tuple[float, int]:
    """``"5:10"`` -> (5.0, 10), for --points."""
    c, sep, window = text.partition(":")
    try:
        if not sep:
            raise ValueError
        return float(c), int(window)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not C:W (e.g. 5:10)") from None


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    parser = argparse.ArgumentParser(
        prog=TOOL,
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Run a grid of ULTHO experiments: scripts x environment ids x methods (ppo: ULTHO off; "
                    "ultho: one run per (c, W); relay: Relay-ULTHO per (c, W), reusing the ultho run; pbt, pb2, "
                    "random: a study of hpo_baselines.py with --population trials) x seeds. "
                    "Restartable: finished runs are skipped, interrupted ones resume from their checkpoints. "
                    "Arguments after -- go to every run.",
        epilog="examples:\n"
               "  python sweep.py --paper minigrid --dry-run                      # the paper's MiniGrid grid\n"
               "  python sweep.py --paper minigrid --total-timesteps 100000       # scaled down, local processes\n"
               "  python sweep.py --paper procgen --ray-address 10.0.0.1:6379 --cpus-per-run 4 --gpus-per-run 0.5\n"
               "  python sweep.py --scripts ppo_ultho_minigrid.py --env-ids MiniGrid-Empty-5x5-v0 \\\n"
               "      --methods ppo ultho --seeds 1 2 3 --out runs/empty -- --num-envs 8\n"
               "  python sweep.py --paper minigrid --seeds 1 2 --track            # W&B group sweep-minigrid\n",
    )
    grid = parser.add_argument_group("grid (a --paper preset fills every field; each given field overrides it)")
    grid.add_argument("--paper", choices=sorted(PRESETS), help="the paper's grid for this benchmark: its script, "
                      "environments and budget, methods ppo ultho relay, c in {1, 5}, W in {10, 50, 100}, seeds 1-5")
    grid.add_argument("--scripts", nargs="+", metavar="SCRIPT", help="training scripts")
    grid.add_argument("--env-ids", nargs="+", metavar="ENV_ID", help="environment ids (each with every script)")
    grid.add_argument("--methods", nargs="+", choices=METHODS, help="ppo ultho relay (the paper's grid), grid "
                      "(every fixed setting of the search space, each a run with --no-ultho) and the HPO baselines "
                      "of hpo_baselines.py, pbt pb2 random (default: a preset's ppo ultho relay, else ppo ultho)")
    grid.add_argument("--grid-clusters", nargs="+", metavar="ITEM",
                      help="the grid method's clusters: every combination of their values is a fixed-settings run "
                           "(NAME takes the script's values, NAME=V1,V2,... sets them; default: the script's search "
                           "space, e.g. 27 settings for MiniGrid)")
    grid.add_argument("--population", type=int, default=4, metavar="N",
                      help="trials of a pbt or pb2 study, samples of a random one (default 4)")
    grid.add_argument("--c", nargs="+", type=float, metavar="C", help="ULTHO's exploration coefficients (default 5)")
    grid.add_argument("--window", nargs="+", type=int, metavar="W", help="ULTHO's windows (default 10)")
    grid.add_argument("--points", nargs="+", type=parse_point, metavar="C:W",
                      help="(c, W) pairs for ultho and relay, e.g. 5:10 1:50, instead of every --c with every "
                           "--window"),
    grid.add_argument("--variants", nargs="+", type=parse_variant, metavar="STRATEGY:CREDIT:SCALE",
                      help="the bandit's variants for ultho and relay, e.g. ts:improvement:running (default "
                           "ucb:level:none, the paper's; docs/strategies.md)")
    grid.add_argument("--seeds", nargs="+", type=int, metavar="SEED", help="seeds (default 1)")
    grid.add_argument("--total-timesteps", type=int, metavar="N",
                      help="steps per run (default: the preset's budget, else the script's default)")
    execution = parser.add_argument_group("execution")
    execution.add_argument("--out", metavar="DIR",
                           help="sweep directory: runs/, relays/, logs/, sweep.json (default runs/sweep-<preset>)")
    execution.add_argument("--workers", type=int, metavar="N",
                           help="local runs at a time (default: the machine's cores / --cpus-per-run)")
    execution.add_argument("--ray-address", metavar="ADDR",
                           help="submit every run as a task to this running Ray cluster (e.g. 10.0.0.1:6379)")
    execution.add_argument("--cpus-per-run", type=float, default=1, metavar="N", help="CPUs a run needs (default 1)")
    execution.add_argument("--gpus-per-run", type=float, default=0, metavar="N",
                           help="GPUs a Ray task reserves, fractions allowed (default 0; local runs ignore it)")
    execution.add_argument("--done-from", metavar="DIR",
                           help="a folder of exported runs (ultho_report.py --export-data DIR, e.g. committed "
                                "results): each grid point exported there counts as done and is restored into --out")
    execution.add_argument("--max-retries", type=int, default=2, metavar="N",
                           help="times a failed or interrupted run is resumed from its checkpoint (default 2)")
    execution.add_argument("--dry-run", action="store_true",
                           help="print every run's command and the compute it needs; run nothing (with --track, no "
                                "W&B login is needed for it)")
    add_tracking_options(parser, "every run of the sweep (a relay's and a study's runs too)",
                         "the name of the --out directory")
    return parse_split_args(parser, argv)


def main(argv: list[str]) -> int:
    try:
        args, extra_args = parse_args(argv)
        preset = PRESETS.get(args.paper)
        scripts = args.scripts or ([preset.script] if preset else None)
        env_ids = args.env_ids or (list(preset.env_ids) if preset else None)
        if not scripts or not env_ids:
            raise UsageError("give --paper PRESET, or --scripts and --env-ids")
        methods = args.methods or (["ppo", "ultho", "relay"] if preset else ["ppo", "ultho"])
        if args.points and (args.c or args.window):
            raise UsageError("--points gives the (c, W) pairs itself; leave out --c and --window")
        c_values = args.c or (list(PAPER_C) if preset else [5.0])
        windows = args.window or (list(PAPER_WINDOWS) if preset else [10])
        points = args.points or list(itertools.product(c_values, windows))
        if args.points:
            c_values = sorted({c for c, _ in points})
            windows = sorted({w for _, w in points})
        seeds = args.seeds or (list(PAPER_SEEDS) if preset else [1])
        total_timesteps = args.total_timesteps or (preset.total_timesteps if preset else None)
        variants = args.variants or [PAPER_VARIANT]
        for name, values in (("--methods", methods), ("--c", c_values), ("--window", windows), ("--seeds", seeds),
                             ("--variants", [":".join(v) for v in variants]),
                             ("--points", [f"{format_value(c)}:{w}" for c, w in points])):
            if len(set(values)) != len(values):
                raise UsageError(f"{name} {' '.join(map(str, values))}: a value is given twice")
        if any(not (math.isfinite(c) and c >= 0) for c in c_values) or any(w < 1 for w in windows):
            raise UsageError("--c must be finite and >= 0, --window >= 1")
        for name, value in (("--total-timesteps", args.total_timesteps), ("--workers", args.workers),
                            ("--population", args.population)):
            if value is not None and value <= 0:
                raise UsageError(f"{name} must be positive, got {value}")
        if args.done_from is not None and not os.path.isdir(args.done_from):
            raise UsageError(f"--done-from {args.done_from}: no such directory")
        if args.max_retries < 0 or args.cpus_per_run <= 0 or args.gpus_per_run < 0:
            raise UsageError("--max-retries and --gpus-per-run must be >= 0, --cpus-per-run positive")
        for token in extra_args:
            for flag in ("--env-id", "--seed", "--total-timesteps", "--ultho-c", "--ultho-window", "--no-ultho",
                         "--ultho-strategy", "--ultho-credit", "--ultho-scale", "--run-name", "--runs-dir", "--resume",
                         "--init-from"):
                if token == flag or token.startswith(flag + "="):
                    raise UsageError(f"{flag} after -- is set by the grid; use the grid's own options")
        # Absolute, because a Ray task's working directory is not the driver's.
        out = os.path.abspath(args.out or os.path.join("runs", f"sweep-{args.paper or 'custom'}"))
        tracking = tracking_flags(args, extra_args, os.path.basename(out), check_login=not args.dry_run)
        grid = {"scripts": [os.path.basename(s) for s in scripts], "env_ids": env_ids, "methods": methods,
                "c": c_values, "window": windows, "points": [[c, w] for c, w in points],
                "variants": [":".join(v) for v in variants], "seeds": seeds, "population": args.population,
                "total_timesteps": total_timesteps, "grid_clusters": args.grid_clusters,
                "extra_args": extra_args}
        # A study's trials go to the same Ray cluster as the runs, or to a Ray instance of its own with the CPUs
        # of one run.
        study_resources = (("--ray-address", args.ray_address) if args.ray_address else
                           ("--num-cpus", str(max(1, int(args.cpus_per_run)))))
        if args.grid_clusters and "grid" not in methods:
            raise UsageError("--grid-clusters sets the grid method's clusters; add grid to --methods")
        runs = expand(scripts, env_ids, methods, points, seeds, total_timesteps, extra_args, out, tuple(variants),
                      args.population, study_resources, args.grid_clusters)
        track(runs, tracking)
        fixed = {token for run in runs if run.method == "grid" for token in setting_flags(run.settings)[::2]}
        for token in extra_args:
            if token.split("=", 1)[0] in fixed:
                raise UsageError(f"{token.split('=', 1)[0]} after -- is set by the grid method; use --grid-clusters")

        if args.dry_run:
            for run in runs:
                print(" ".join(run.command()))
            budget = total_timesteps
            if budget is None:
                print(f"{len(runs)} runs; steps per run are the scripts' defaults", file=sys.stderr)
            else:
                steps = total_steps(runs, lambda run: budget, args.population)
                hours = ""
                if preset and args.scripts is None:
                    h = steps / preset.measured_sps / 3600
                    hours = f", {h:,.{1 if h < 10 else 0}f} hours at {preset.measured_sps:,.0f} steps/s"
                print(f"{len(runs)} runs, {steps:,} environment steps{hours}", file=sys.stderr)
            return 0

        for run in runs:
            run.script = resolve_script(run.script)
        workers = args.workers or max(1, int((os.cpu_count() or 1) // args.cpus_per_run))
        executor = (RayExecutor(args.ray_address, args.cpus_per_run, args.gpus_per_run, args.max_retries)
                    if args.ray_address else LocalExecutor(workers))
        try:
            return 0 if sweep(runs, grid, out, executor, args.max_retries,
                              log=lambda line: print(line, flush=True), done_from=args.done_from) else 1
        finally:
            executor.close()
    except UsageError as err:
        print_error(TOOL, err)
        return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

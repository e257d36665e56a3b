"""This project's scripts against CleanRL's, side by side: whole-process wall time and peak memory.

Each benchmark trains the same number of steps at the paper's settings (SAC on DMC: CleanRL's defaults) with
CleanRL's script and with ours (ULTHO on, and --no-ultho; for ALE and Procgen each also with --precision bf16),
alternating all of them in every round so that drifting machine load hits all alike. A run is timed from process
start to exit (imports, environment construction and start-up included) and its peak resident memory is read from
the kernel's accounting of that process (``os.wait4``). The table gives medians over the rounds and ratios:
CleanRL's wall time over ours (above 1: ours is faster) and our peak memory over CleanRL's.

CLEANRL_DIR holds the five scripts of CleanRL's ``cleanrl/`` (https://github.com/vwxyzjn/cleanrl; measured with
commit fe8d8a0), copied flat with ``cleanrl_utils/`` (``__init__.py``, ``atari_wrappers.py``, ``buffers.py``)
beside them, kept outside this repository and adapted minimally to this project's pinned gymnasium 1.4:

- ``ppo.py``: ``import minigrid``, and ``FlattenObservation(ImgObsWrapper(env))`` after ``gym.make`` (MiniGrid's
  image, flattened: the network is the same 64-unit MLP as ours);
- ``ppo_atari.py``: ``gym.register_envs(ale_py)``; gymnasium 1.x names ``GrayscaleObservation`` and
  ``FrameStackObservation``; it needs opencv (``ResizeObservation``);
- ``ppo_continuous_action.py``: ``import pybullet_envs_gymnasium``; ``TransformObservation`` gets its
  observation space (gymnasium 1.x's signature);
- those three: ``SyncVectorEnv(..., autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)`` (the autoreset CleanRL
  was written for; 1.x's default would store a reset as a transition) and the episode-logging loop rewritten
  for 1.x's ``final_info`` (one dict of arrays with an ``_episode`` mask);
- ``ppo_procgen.py``: unchanged, run with gym 0.23.1 (the gym it was written for; 0.26 breaks its reset);
- ``sac_continuous_action.py``: ``make_env`` builds the task as ``DMCEnv(env_id)``, imported from
  ``sac_ultho_dmc`` (the suite task with its observation dict flattened, the environment our script steps;
  this benchmark puts the repository on CleanRL's PYTHONPATH), instead of ``gym.make(env_id)``;
  ``SyncVectorEnv(..., autoreset_mode=gym.vector.AutoresetMode.SAME_STEP)``; the episode-logging loop
  rewritten for 1.x's ``final_info``; ``infos["final_obs"]`` for 0.29's ``infos["final_observation"]``.

Both sides run the paper's settings (the flags below). What still differs: CleanRL's ``ppo_atari.py`` sign-clips
rewards where ours normalizes them, and steps Python wrappers around single games where ours uses ALE's C++
vector environment; CleanRL's ``ppo_procgen.py`` trains on the full level distribution, so ours gets
``--num-levels 0`` here; each side uses its own default torch threads (ours: one for MiniGrid and PyBullet, one
per core for ALE and Procgen, one for SAC; CleanRL: torch's default, one per core). SAC on DMC runs CleanRL's
defaults on both sides (cheetah-run; 5,000 random steps, then an update per step), so the row measures
mostly the updates; ours also differs from CleanRL's SAC in what docs/dmc.md lists (the entropy
coefficient's step reuses the policy loss's log-probabilities).

``--cleanrl-python`` is the interpreter for CleanRL's scripts (a virtual environment with this project's
requirements plus opencv-python-headless and gym==0.23.1); ours run with this interpreter.

Usage: python benchmarks/bench_cleanrl.py CLEANRL_DIR [--cleanrl-python PY] [--benchmarks minigrid atari ...]
       [--rounds 3] [--steps N]
"""

import argparse
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


@dataclass(frozen=True)
class Benchmark:
    ours: str
    ours_args: tuple[str, ...]
    cleanrl: str
    cleanrl_args: tuple[str, ...]
    steps: int
    precisions: tuple[str, ...] = ("float32",)  # ours also runs in each other one (--precision), side by side
    baseline: str = "PPO"  # what our script is with --no-ultho
    cleanrl_imports_ours: bool = False  # CleanRL's adapted script imports from this repository (PYTHONPATH)


# The paper's settings on both sides: CleanRL takes minibatches by count (rollout / minibatch size), anneals the
# learning rate unless told not to, and defaults to its own values where ours differ.
BENCHMARKS = {
    "minigrid": Benchmark(
        "ppo_ultho_minigrid.py", ("--env-id", "MiniGrid-DoorKey-6x6-v0"),
        "ppo.py", ("--env-id", "MiniGrid-DoorKey-6x6-v0", "--num-envs", "16", "--num-steps", "128",
                   "--num-minibatches", "8", "--update-epochs", "4", "--learning-rate", "1e-3", "--no-anneal-lr",
                   "--ent-coef", "0.01"),
        102_400),
    "pybullet": Benchmark(
        "ppo_ultho_pybullet.py", ("--env-id", "HalfCheetahBulletEnv-v0"),
        "ppo_continuous_action.py", ("--env-id", "HalfCheetahBulletEnv-v0", "--num-envs", "1", "--num-steps", "2048",
                                     "--num-minibatches", "32", "--update-epochs", "10", "--learning-rate", "2e-4",
                                     "--no-anneal-lr", "--no-clip-vloss"),
        20_480),
    "atari": Benchmark(
        "ppo_ultho_atari.py", ("--env-id", "BattleZone"),
        "ppo_atari.py", ("--env-id", "BattleZoneNoFrameskip-v4", "--num-envs", "8", "--num-steps", "128",
                         "--num-minibatches", "4", "--update-epochs", "4", "--learning-rate", "2.5e-4",
                         "--no-anneal-lr", "--clip-coef", "0.2"),
        10_240, ("float32", "bf16")),
    "procgen": Benchmark(
        "ppo_ultho_procgen.py", ("--env-id", "starpilot", "--num-levels", "0"),
        "ppo_procgen.py", ("--env-id", "starpilot", "--num-envs", "64", "--num-steps", "256", "--num-minibatches", "8",
                           "--update-epochs", "3", "--learning-rate", "5e-4", "--no-anneal-lr"),
        16_384, ("float32", "bf16")),
    "dmc": Benchmark(
        "sac_ultho_dmc.py", ("--env-id", "cheetah-run"),
        "sac_continuous_action.py", ("--env-id", "cheetah-run"),
        15_000, baseline="SAC", cleanrl_imports_ours=True),
}


def timed(command: list[str], cwd: str, env: dict | None = None) -> tuple[float, float]:
    """(wall seconds, peak resident MB) of one process, start to exit."""
    start = time.perf_counter()
    process = subprocess.Popen(command, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(process.pid, 0)
    wall = time.perf_counter() - start
    process.returncode = os.waitstatus_to_exitcode(status)
    stderr = process.stderr.read().decode(errors="replace")
    if process.returncode != 0:
        raise SystemExit(f"bench_cleanrl: {' '.join(command)} failed ({process.returncode}):\n{stderr[-2000:]}")
    return wall, usage.ru_maxrss / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("cleanrl_dir", help="folder holding CleanRL's (adapted) scripts")
    parser.add_argument("--cleanrl-python", default=sys.executable, help="interpreter for CleanRL's scripts")
    parser.add_argument("--benchmarks", nargs="+", choices=sorted(BENCHMARKS), default=list(BENCHMARKS))
    parser.add_argument("--rounds", type=int, default=3, help="alternating rounds (default 3)")
    parser.add_argument("--steps", type=int, help="steps per run instead of each benchmark's own (a smoke test)")
    # One flag per --extra, written with "=": argparse reads a bare "--torch-threads" as an option of its own.
    parser.add_argument("--extra", action="append", default=[], metavar="FLAG=VALUE",
                        help="a flag added to our runs only, e.g. --extra=--torch-threads=2 (repeat for more)")
    args = parser.parse_args()
    if args.rounds < 1:
        parser.error(f"--rounds must be at least 1, got {args.rounds}")
    if args.steps is not None and args.steps < 1:
        parser.error(f"--steps must be at least 1, got {args.steps}")
    for benchmark in args.benchmarks:
        path = os.path.join(args.cleanrl_dir, BENCHMARKS[benchmark].cleanrl)
        if not os.path.isfile(path):
            parser.error(f"{path}: no such file")

    print(f"# CleanRL vs this project, whole-process wall time ({platform.machine()}, {os.cpu_count()} cores, "
          f"Python {platform.python_version()}, {args.rounds} alternating rounds, medians)")
    print("| benchmark | steps | ours | CleanRL s | ours s | CleanRL / ours | peak MB CleanRL | peak MB ours "
          "| memory ours / CleanRL |")
    print("|---|---|---|---|---|---|---|---|---|")
    for name in args.benchmarks:
        bench = BENCHMARKS[name]
        steps = str(args.steps or bench.steps)
        pythonpath = os.pathsep.join(filter(None, [REPO, os.environ.get("PYTHONPATH")]))
        cleanrl_env = {**os.environ, "PYTHONPATH": pythonpath} if bench.cleanrl_imports_ours else None
        with tempfile.TemporaryDirectory() as scratch:
            configs = {"CleanRL": ([args.cleanrl_python, os.path.join(os.path.abspath(args.cleanrl_dir), bench.cleanrl),
                                    *bench.cleanrl_args, "--total-timesteps", steps, "--seed", "1"], scratch)}
            for precision in bench.precisions:
                for method, flags in (("ULTHO", []), (bench.baseline, ["--no-ultho"])):
                    label = method if precision == "float32" else f"{method}, {precision}"
                    extra = ["--precision", precision] if precision != "float32" else []
                    configs[label] = ([sys.executable, os.path.join(REPO, bench.ours), *bench.ours_args,
                                       "--total-timesteps", steps, "--eval-episodes", "0", "--quiet", "--runs-dir",
                                       scratch, *flags, *extra, *args.extra], REPO)
            results: dict[str, list[tuple[float, float]]] = {key: [] for key in configs}
            for round_ in range(args.rounds):
                for key, (command, cwd) in configs.items():
                    if key != "CleanRL":
                        command = [*command, "--run-name", f"{key.lower().replace(', ', '_')}{round_}"]
                    results[key].append(timed(command, cwd, cleanrl_env if key == "CleanRL" else None))
        wall = {key: statistics.median(w for w, _ in runs) for key, runs in results.items()}
        peak = {key: max(m for _, m in runs) for key, runs in results.items()}
        for key in configs:
            if key == "CleanRL":
                continue
            print(f"| {name} | {int(steps):,} | {key} | {wall['CleanRL']:.1f} | {wall[key]:.1f} | "
                  f"{wall['CleanRL'] / wall[key]:.2f}x | {peak['CleanRL']:,.0f} | {peak[key]:,.0f} | "
                  f"{peak[key] / peak['CleanRL']:.2f} |", flush=True)

if __name__ == "__main__":
    main()

"""The price of the HPO baselines' machinery: wall time of a PBT population of N trials (hpo_baselines.py on a
local Ray instance) against N plain runs of the same steps, the same number at a time, side by side; and a
random-search study of N trials, which has the segments and Ray but no exploit, between the two.

Each trial of a study runs in segments of --interval steps, one process of the script each (torch import,
environments rebuilt from the checkpoint), and synchronous PBT pauses every trial at every perturbation until
the whole population is there. The table separates that from the training itself: "training" is the trials'
own wall time as their summary.json states it (summed over segments for a study), "overhead" the rest.

Usage: python benchmarks/bench_hpo.py [--population 4] [--steps 102400] [--interval 20480] [--cpus 2]
"""

import argparse
import concurrent.futures
import json
import os
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import REPO, machine

SCRIPT = "ppo_ultho_minigrid.py"


def plain_runs(args: argparse.Namespace, script_args: list[str], runs_dir: str) -> tuple[float, float]:
    """N --no-ultho runs, --cpus at a time: (wall time, the runs' own training time summed)."""
    def one(k: int) -> float:
        subprocess.run([sys.executable, os.path.join(REPO, SCRIPT), *script_args, "--no-ultho", "--seed", str(1000 + k),
                        "--eval-episodes", "0", "--runs-dir", runs_dir, "--run-name", f"plain_{k}", "--quiet"],
                       check=True, cwd=REPO)
        with open(os.path.join(runs_dir, f"plain_{k}", "summary.json")) as f:
            return json.load(f)["wall_time_s"]

    start = time.perf_counter()
    with concurrent.futures.ThreadPoolExecutor(args.cpus) as pool:
        training = sum(pool.map(one, range(args.population)))
    return time.perf_counter() - start, training


def study(args: argparse.Namespace, method: str, script_args: list[str], study_dir: str) -> tuple[float, float, int]:
    """A study of hpo_baselines.py: (wall time, the trials' training time summed, exploits)."""
    size = ["--samples" if method == "random" else "--population", str(args.population)]
    start = time.perf_counter()
    subprocess.run([sys.executable, os.path.join(REPO, "hpo_baselines.py"), SCRIPT, "--method", method, *size,
                    "--interval", str(args.interval), "--num-cpus", str(args.cpus), "--study-dir", study_dir,
                    "--quiet", "--", *script_args, "--eval-episodes", "0"], check=True, cwd=REPO)
    wall = time.perf_counter() - start
    with open(os.path.join(study_dir, "study.json")) as f:
        record = json.load(f)
    # A segment's summary.json carries the run's wall time so far (the counters go on from the checkpoint), so
    # the last segment's is the trial's training time; each segment's own process time is in the trial record.
    training = 0.0
    for trial in record["trials"]:
        with open(os.path.join(study_dir, trial["run_dir"], "summary.json")) as f:
            training += json.load(f)["wall_time_s"]
    return wall, training, len(record["exploits"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--population", type=int, default=4, help="trials of the study, and plain runs (default 4)")
    parser.add_argument("--steps", type=int, default=102_400, help="steps per trial and per plain run")
    parser.add_argument("--interval", type=int, default=20_480, help="steps between perturbations (default 20,480: "
                        "five segments of ten iterations)")
    parser.add_argument("--cpus", type=int, default=2, help="runs or trials at a time (default 2)")
    parser.add_argument("--env-id", default="MiniGrid-DoorKey-6x6-v0")
    parser.add_argument("--script-args", nargs=argparse.REMAINDER, default=[],
                        help="more arguments for every run, e.g. --num-envs 4 --num-steps 64 (last on the line)")
    args = parser.parse_args()
    script_args = ["--env-id", args.env_id, "--total-timesteps", str(args.steps), *args.script_args]
    rows = []
    with tempfile.TemporaryDirectory() as scratch:
        wall, training = plain_runs(args, script_args, os.path.join(scratch, "plain"))
        rows.append((f"{args.population} plain runs (--no-ultho)", wall, training, None))
        for method in ("random", "pbt"):
            wall, training, exploits = study(args, method, script_args, os.path.join(scratch, method))
            rows.append((f"{method} study of {args.population} trials", wall, training, exploits))
    steps = args.population * args.steps
    reference = rows[0][1]
    print(f"# hpo_baselines.py overhead: {args.env_id}, {args.population} x {args.steps:,} steps, interval "
          f"{args.interval:,}, {args.cpus} at a time  ({machine()})")
    print("| what | wall time, s | steps/s | training, s (summed) | overhead, s | exploits | wall time ratio |")
    print("|---|---|---|---|---|---|---|")
    for name, wall, training, exploits in rows:
        print(f"| {name} | {wall:,.1f} | {steps / wall:,.0f} | {training:,.1f} | {wall - training / args.cpus:,.1f} | "
              f"{'-' if exploits is None else exploits} | {wall / reference:.3f} |")
    print("\noverhead: wall time minus the summed training time divided by the runs at a time (an estimate: "
          "process starts, checkpoints, Ray and Tune, and trials waiting for the population at each perturbation)")


if __name__ == "__main__":
    main()

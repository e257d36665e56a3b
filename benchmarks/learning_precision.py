"""Learning parity of --precision bf16 against float32: the same PPO runs in both precisions, their scores and
learning curves side by side.

The gradient-agreement tests show that one bf16 update moves the network almost as a float32 update does; this
experiment shows what that means over a whole training run. It trains fixed-settings PPO (``--no-ultho``) of an
ALE or Procgen script on one environment for a few seeds in both precisions through ``sweep.py`` (one sweep
per precision, the two side by side, one torch thread per run), so that killed and started again it resumes
where it stopped and reruns no finished run. Then it prints a markdown table (per seed: final score, evaluation
score, steps/s; the mean and the difference bf16 - float32) and, with ``--figure``, draws each precision's
return curve (mean over seeds, one thin line per seed). ``--csv`` writes every run's return curve as one CSV
(precision, seed, step, return), from which the figure can be redrawn without the runs (``--from-csv``).

Usage:
    python benchmarks/learning_precision.py                      # ALE Breakout, 300K steps, seeds 1-5
    python benchmarks/learning_precision.py --script ppo_ultho_procgen.py --env-id coinrun --total-timesteps 2000000
    python benchmarks/learning_precision.py --no-run --figure parity.png --csv parity.csv   # report finished runs

A run's score does not depend on the machine's load (only its speed does), so this may share the machine with
other work; the steps/s column then does not mean much (``bench_atari.py --sections precision`` measures speed).
"""

import argparse
import csv
import json
import os
import statistics
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import REPO, machine

sys.path.insert(0, REPO)
from ultho_reporting.runs import RETURN_TAG, Study

PRECISIONS = ("float32", "bf16")


def sweep_command(args: argparse.Namespace, precision: str) -> list[str]:
    return [sys.executable, os.path.join(REPO, "sweep.py"), "--scripts", args.script, "--env-ids", args.env_id,
            "--methods", "ppo", "--seeds", *map(str, args.seeds), "--total-timesteps", str(args.total_timesteps),
            "--workers", "1", "--out", f"{args.out}-{precision}", "--", "--torch-threads", "1",
            "--precision", precision]


def run_sweeps(args: argparse.Namespace) -> None:
    """Both precisions' sweeps at once, each one run at a time: the two precisions progress side by side."""
    processes = [subprocess.Popen(sweep_command(args, precision), cwd=REPO) for precision in PRECISIONS]
    codes = [process.wait() for process in processes]
    if any(codes):
        sys.exit(f"learning_precision.py: a sweep failed (exit statuses {codes}); run the same command again to resume")


def load_runs(args: argparse.Namespace) -> dict[str, dict[int, dict]]:
    """{precision: {seed: {"summary": summary.json, "curve": (T, 2) step/return}}} of the finished runs."""
    study = Study()
    runs: dict[str, dict[int, dict]] = {}
    for precision in PRECISIONS:
        runs_dir = os.path.join(f"{args.out}-{precision}", "runs")
        runs[precision] = {}
        for name in sorted(os.listdir(runs_dir)) if os.path.isdir(runs_dir) else []:
            path = os.path.join(runs_dir, name, "summary.json")
            if not os.path.exists(path):
                continue
            with open(path) as f:
                summary = json.load(f)
            if summary.get("precision", "float32") != precision or int(summary["seed"]) not in args.seeds:
                continue
            curve = study.read_scalars(os.path.join(runs_dir, name)).get(RETURN_TAG, np.zeros((0, 2)))
            runs[precision][int(summary["seed"])] = {"summary": summary, "curve": curve}
    return runs


def print_table(args: argparse.Namespace, runs: dict[str, dict[int, dict]]) -> None:
    def score(precision: str, seed: int, key: str) -> float | None:
        run = runs[precision].get(seed)
        if run is None:
            return None
        return run["summary"]["eval"]["mean_return"] if key == "eval" else run["summary"][key]

    def text(value: float | None, digits: int = 1) -> str:
        return "-" if value is None else f"{value:,.{digits}f}"

    print(f"# Learning parity, {args.script} --no-ultho on {args.env_id}, {args.total_timesteps:,} steps "
          f"({machine()})")
    print("| seed | final float32 | final bf16 | eval float32 | eval bf16 | steps/s float32 | steps/s bf16 |")
    print("|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        cells = [text(score(p, seed, key), 0 if key == "sps" else 1) for key in ("final_score", "eval", "sps")
                 for p in PRECISIONS]
        print(f"| {seed} | " + " | ".join(cells) + " |")
    means = {}
    for key in ("final_score", "eval", "sps"):
        for precision in PRECISIONS:
            values = [v for seed in args.seeds if (v := score(precision, seed, key)) is not None]
            means[key, precision] = statistics.mean(values) if values else None
    print("| mean | " + " | ".join(text(means[key, p], 0 if key == "sps" else 1)
                                  for key in ("final_score", "eval", "sps") for p in PRECISIONS) + " |")
    complete = all(len(runs[p]) == len(args.seeds) for p in PRECISIONS)
    if complete:
        for key, label in (("final_score", "final score"), ("eval", "evaluation score")):
            diffs = [score("bf16", seed, key) - score("float32", seed, key) for seed in args.seeds]
            print(f"\n{label}, bf16 - float32: mean {statistics.mean(diffs):+.1f} "
                  f"(per seed {', '.join(f'{d:+.1f}' for d in diffs)})", end="")
        print()
    else:
        print("\nfinished runs: " + ", ".join(f"{p} {len(runs[p])}/{len(args.seeds)}" for p in PRECISIONS))


def write_csv(path: str, runs: dict[str, dict[int, dict]]) -> None:
    temporary = path + ".tmp"
    with open(temporary, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["precision", "seed", "step", "return"])
        for precision, by_seed in runs.items():
            for seed, run in sorted(by_seed.items()):
                writer.writerows([precision, seed, int(step), repr(float(value))] for step, value in run["curve"])
    os.replace(temporary, path)


def read_csv(path: str) -> dict[str, dict[int, dict]]:
    points: dict[tuple[str, int], list[tuple[float, float]]] = {}
    with open(path, newline="") as f:
        for row in csv.DictReader(f):
            points.setdefault((row["precision"], int(row["seed"])), []).append((float(row["step"]),
                                                                               float(row["return"])))
    runs: dict[str, dict[int, dict]] = {p: {} for p in PRECISIONS}
    for (precision, seed), curve in points.items():
        runs.setdefault(precision, {})[seed] = {"curve": np.array(curve)}
    return runs


def draw(path: str, title: str, runs: dict[str, dict[int, dict]]) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    figure, axes = plt.subplots(figsize=(6.4, 3.8))
    for color, precision in zip(("tab:blue", "tab:orange"), PRECISIONS):
        curves = [run["curve"] for run in runs.get(precision, {}).values() if len(run["curve"])]
        if not curves:
            continue
        for curve in curves:
            axes.plot(curve[:, 0], curve[:, 1], color=color, alpha=0.25, linewidth=0.8)
        grid = np.linspace(max(c[0, 0] for c in curves), min(c[-1, 0] for c in curves), 200)
        mean = np.mean([np.interp(grid, c[:, 0], c[:, 1]) for c in curves], axis=0)
        axes.plot(grid, mean, color=color, linewidth=2, label=f"{precision} (mean of {len(curves)} seeds)")
    axes.set_xlabel("environment steps")
    axes.set_ylabel("episodic return (game score)")
    axes.set_title(title, fontsize=10)
    axes.grid(alpha=0.3)
    axes.legend()
    figure.tight_layout()
    figure.savefig(path, dpi=90)
    plt.close(figure)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--script", default="ppo_ultho_atari.py", choices=["ppo_ultho_atari.py",
                                                                           "ppo_ultho_procgen.py"])
    parser.add_argument("--env-id", default="Breakout")
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3, 4, 5])
    parser.add_argument("--total-timesteps", type=int, default=300_000)
    parser.add_argument("--out", default="runs/parity",
                        help="prefix of the two sweep directories, <out>-float32 and <out>-bf16 (default runs/parity)")
    parser.add_argument("--no-run", action="store_true", help="only report the runs that exist")
    parser.add_argument("--figure", help="PNG of the return curves")
    parser.add_argument("--csv", help="write every run's return curve here")
    parser.add_argument("--from-csv", help="draw --figure from such a CSV instead of the runs (no table)")
    args = parser.parse_args()
    if args.total_timesteps <= 0 or any(seed < 0 for seed in args.seeds):
        parser.error(f"--total-timesteps must be positive and --seeds non-negative "
                     f"(got {args.total_timesteps}, {args.seeds})")
    title = f"{args.env_id}, PPO --no-ultho, float32 and bf16"
    if args.from_csv:
        if not args.figure:
            parser.error("--from-csv needs --figure")
        draw(args.figure, title, read_csv(args.from_csv))
        return
    args.out = os.path.abspath(args.out)
    if not args.no_run:
        run_sweeps(args)
    runs = load_runs(args)
    print_table(args, runs)
    if args.csv:
        write_csv(args.csv, runs)
    if args.figure:
        draw(args.figure, title, runs)


if __name__ == "__main__":
    main()

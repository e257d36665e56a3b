"""Throughput and peak memory of ppo_ultho_procgen.py at the paper's settings (64 envs x 256 steps, minibatch
2048, 3 epochs), ULTHO on and off side by side, ULTHO's own cost, and the environment's own ceiling (64
starpilot games in procgen's vector env, random actions). Then float32 and bf16 (--precision) side by side, as
plain PPO (--no-ultho) so that both do the same work: SPS, their ratio, peak memory, and the shares of the wall
time in the rollout and in the update (each run's summary.json).

One iteration is 16,384 steps, so a run of a few iterations per configuration is enough. Peak resident memory
is the training process's own (summary.json's peak_rss_mb, getrusage's ru_maxrss); on a GPU, peak_cuda_mb is
the CUDA allocator's peak. --update-chunk is the script's automatic one (512 on the CPU, none on CUDA).

Usage: python benchmarks/bench_procgen.py [--steps 32768] [--repeats 2] [--cuda] [--env-threads 1]
"""

import argparse
import contextlib
import io
import os
import statistics
import sys
import time

import numpy as np

with contextlib.redirect_stderr(io.StringIO()):
    import procgen

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import machine, precision_side_by_side, print_precision_table, run_script

SCRIPT = "ppo_ultho_procgen.py"


def env_only_steps_per_second(env_id: str, num_envs: int, steps: int, threads: int) -> float:
    envs = procgen.ProcgenGym3Env(num=num_envs, env_name=env_id, num_levels=200, start_level=0,
                                  distribution_mode="easy", rand_seed=0, num_threads=threads)
    actions = np.random.default_rng(0).integers(0, 15, (steps // num_envs, num_envs), dtype=np.int32)
    start = time.perf_counter()
    for a in actions:
        envs.act(a)
        envs.observe()
    return len(actions) * num_envs / (time.perf_counter() - start)


def ultho_on_off_table(args: argparse.Namespace, base: list[str]) -> None:
    """PPO, ULTHO over a neutral space and ULTHO over the paper's, alternating; the environment alone."""
    neutral = ["learning_rate=0.0005", "minibatch_size=2048", "vf_coef=0.5", "update_epochs=3"]
    configurations = {"PPO (--no-ultho)": ["--no-ultho"], "ULTHO, neutral space": ["--ultho-clusters", *neutral],
                      "ULTHO, paper space": ["--ultho"]}
    sps: dict[str, list[float]] = {name: [] for name in configurations}
    rss: dict[str, list[float]] = {name: [] for name in configurations}
    shares: list[float] = []
    device = "?"
    # Alternating, so drifting machine load hits every configuration alike.
    for _ in range(args.repeats):
        for name, extra in configurations.items():
            summary = run_script(SCRIPT, [*base, *extra])
            sps[name].append(summary["sps"])
            rss[name].append(summary["peak_rss_mb"])
            device = summary["device"]
            if summary["ultho_share"] is not None and name != "PPO (--no-ultho)":
                shares.append(summary["ultho_share"])
    env_alone = [env_only_steps_per_second(args.env_id, 64, 16_384, args.env_threads) for _ in range(args.repeats)]

    ref = statistics.median(sps["PPO (--no-ultho)"])
    print(f"# {SCRIPT} on {args.env_id}, 64 envs x 256 steps, {args.steps} steps per run, training on {device}  "
          f"({machine()})")
    print("| what | median steps/s | min | max | ratio to PPO | peak RSS (MB, max) |")
    print("|---|---|---|---|---|---|")
    for name in configurations:
        med = statistics.median(sps[name])
        print(f"| {name} | {med:,.0f} | {min(sps[name]):,.0f} | {max(sps[name]):,.0f} | {med / ref:.3f} | "
              f"{max(rss[name]):,.0f} |")
    print(f"| env alone (ceiling) | {statistics.median(env_alone):,.0f} | {min(env_alone):,.0f} | "
          f"{max(env_alone):,.0f} | {statistics.median(env_alone) / ref:.1f} | |")
    neutral_sps = statistics.median(sps["ULTHO, neutral space"])
    print(f"\nULTHO's cost, SPS of the neutral space vs PPO (identical training): "
          f"{100 * (1 - neutral_sps / ref):+.1f}% (medians of {args.repeats} alternating runs)")
    print(f"ULTHO's cost, measured inside each ULTHO run (select, credit, apply, bandit logging as a share of "
          f"wall time): median {100 * statistics.median(shares):.3f}%, max {100 * max(shares):.3f}%")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="starpilot")
    parser.add_argument("--steps", type=int, default=32_768, help="training steps per run (2 iterations; paper: 25M)")
    parser.add_argument("--repeats", type=int, default=2,
                        help="rounds of alternating runs (the three ULTHO configurations, then the two precisions)")
    parser.add_argument("--cuda", action=argparse.BooleanOptionalAction, default=False,
                        help="train on the GPU when there is one (default: CPU)")
    parser.add_argument("--env-threads", type=int, default=1,
                        help="procgen's worker threads, for the training runs and the environment alone (the "
                             "script's default 1 suits 2 cores; a 16-core GPU host wants more)")
    parser.add_argument("--sections", nargs="+", choices=("ultho", "precision"), default=["ultho", "precision"],
                        help="which tables: ULTHO on and off, float32 against bf16 (default both)")
    args = parser.parse_args()
    base = ["--env-id", args.env_id, "--total-timesteps", str(args.steps), "--cuda" if args.cuda else "--no-cuda",
            "--env-threads", str(args.env_threads)]
    if "ultho" in args.sections:
        ultho_on_off_table(args, base)
        print()
    if "precision" in args.sections:
        runs = precision_side_by_side(SCRIPT, [*base, "--no-ultho"], args.repeats)
        print_precision_table(f"{SCRIPT} --no-ultho on {args.env_id}, 64 envs x 256 steps, float32 vs bf16", runs)


if __name__ == "__main__":
    main()

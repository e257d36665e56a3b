"""Throughput of ppo_ultho_pybullet.py at the paper's settings (1 env x 2048 steps, minibatch 64, 10 epochs),
ULTHO on and off side by side, ULTHO's own cost, and the environment's own ceiling (one environment stepped
with random actions, as the script steps it).

On a shared machine the absolute figures drift with the load, so the benchmark also runs the script in this
process with the environment's step() timed: the share of training wall time spent inside step() is
measured in one run, under one load, and times 2,800 (the environment's own rate on an idle 2-core machine of
the CI kind, where CleanRL's ppo_continuous_action.py at these settings makes about 810 SPS) gives the SPS the
script reaches there.

Usage: python benchmarks/bench_pybullet.py [--env-id HalfCheetahBulletEnv-v0] [--steps 20480] [--repeats 3]
"""

import argparse
import os
import statistics
import sys
import tempfile
import time

import gymnasium as gym
import numpy as np
import pybullet_envs_gymnasium  # noqa: F401  (registers the *BulletEnv-v0 environments)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import REPO, print_table, ultho_on_off

sys.path.insert(0, REPO)
import ppo_ultho_pybullet as script

IDLE_ENV_STEPS_PER_SECOND = 2800


def env_only_steps_per_second(env_id: str, steps: int) -> float:
    env = gym.make(env_id)
    env.reset(seed=0)
    actions = np.random.default_rng(0).uniform(env.action_space.low, env.action_space.high,
                                               (steps,) + env.action_space.shape).astype(np.float32)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    seconds = time.perf_counter() - start
    env.close()
    return steps / seconds


def env_share_of_training(env_id: str, steps: int, extra: list[str]) -> float:
    """Trains in this process with every environment's step() timed; returns the share of wall time in it."""
    env_seconds = 0.0
    make_env = script.make_env

    def timed_make_env(env_id: str):
        env = make_env(env_id)
        step = env.step

        def timed_step(action):
            nonlocal env_seconds
            start = time.perf_counter()
            result = step(action)
            env_seconds += time.perf_counter() - start
            return result

        env.step = timed_step
        return env

    script.make_env = timed_make_env
    try:
        with tempfile.TemporaryDirectory() as runs_dir:
            start = time.perf_counter()
            script.main(script.parse_args(["--env-id", env_id, "--total-timesteps", str(steps), *extra,
                                           "--eval-episodes", "0", "--quiet", "--runs-dir", runs_dir,
                                           "--run-name", "share"]))
            return env_seconds / (time.perf_counter() - start)
    finally:
        script.make_env = make_env


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="HalfCheetahBulletEnv-v0")
    parser.add_argument("--steps", type=int, default=20_480, help="training steps per run (paper: 2M)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds of the three alternating configurations")
    args = parser.parse_args()
    neutral = ["learning_rate=0.0002", "minibatch_size=64", "vf_coef=0.5"]
    rows, shares = ultho_on_off("ppo_ultho_pybullet.py",
                                ["--env-id", args.env_id, "--total-timesteps", str(args.steps)],
                                neutral, args.repeats)
    rows["env alone (ceiling)"] = [env_only_steps_per_second(args.env_id, 10_000) for _ in range(args.repeats)]
    print_table(f"ppo_ultho_pybullet.py on {args.env_id}, 1 env x 2048 steps, minibatch 64, 10 epochs", rows, shares)
    print(f"\nShare of training wall time inside the environment's step() (in-process runs, alternating), and the "
          f"SPS it implies where the environment steps {IDLE_ENV_STEPS_PER_SECOND:,}/s (CleanRL there: about 810):")
    print("| what | median share | SPS implied |")
    print("|---|---|---|")
    shares_in_env: dict[str, list[float]] = {"PPO (--no-ultho)": [], "ULTHO, paper space": []}
    for _ in range(args.repeats):
        for name, extra in (("PPO (--no-ultho)", ["--no-ultho"]), ("ULTHO, paper space", ["--ultho"])):
            shares_in_env[name].append(env_share_of_training(args.env_id, args.steps, extra))
    for name, values in shares_in_env.items():
        share = statistics.median(values)
        print(f"| {name} | {share:.3f} | {share * IDLE_ENV_STEPS_PER_SECOND:,.0f} |")


if __name__ == "__main__":
    main()

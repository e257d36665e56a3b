"""Throughput of ppo_ultho_pybullet.py at the paper's settings (1 env x 2048 steps, minibatch 64, 10 epochs),
ULTHO on and off side by side, ULTHO's own cost, and the environment's own ceiling (one environment stepped
with random actions, as the script steps it).

The environment's ceiling also makes the figures comparable across machines and loads: SPS as a share of
it. CleanRL's ppo_continuous_action.py at these settings makes about 810 SPS where the environment alone
steps about 2,800/s, a share of 0.29.

Usage: python benchmarks/bench_pybullet.py [--env-id HalfCheetahBulletEnv-v0] [--steps 20480] [--repeats 3]
"""

import argparse
import os
import statistics
import sys
import time

import gymnasium as gym
import numpy as np
import pybullet_envs_gymnasium  # noqa: F401  (registers the *BulletEnv-v0 environments)

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import print_table, ultho_on_off  # noqa: E402


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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="HalfCheetahBulletEnv-v0")
    parser.add_argument("--steps", type=int, default=20_480, help="training steps per run (paper: 2M)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds of the three alternating configurations")
    args = parser.parse_args()
    neutral = ["learning_rate=0.0002", "minibatch_size=64", "vf_coef=0.5"]
    rows, shares = ultho_on_off("ppo_ultho_pybullet.py", ["--env-id", args.env_id, "--total-timesteps", str(args.steps)],
                                neutral, args.repeats)
    rows["env alone (ceiling)"] = [env_only_steps_per_second(args.env_id, 10_000) for _ in range(args.repeats)]
    print_table(f"ppo_ultho_pybullet.py on {args.env_id}, 1 env x 2048 steps, minibatch 64, 10 epochs", rows, shares)
    ceiling = statistics.median(rows["env alone (ceiling)"])
    for name in ("PPO (--no-ultho)", "ULTHO, paper space"):
        share = statistics.median(rows[name]) / ceiling
        print(f"{name}: {share:.2f} of the environment's ceiling (CleanRL: 810 / 2,800 = 0.29); "
              f"where the environment steps 2,800/s that is about {share * 2800:,.0f} SPS")


if __name__ == "__main__":
    main()

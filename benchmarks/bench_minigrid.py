"""Throughput of ppo_ultho_minigrid.py at the paper's settings, ULTHO on and off side by side, ULTHO's own
cost, and the environment's own speed (16 DoorKey-6x6 envs in gymnasium's synchronous vector env, random actions)
with MiniGrid's gen_obs and with the script's exact re-implementation of it (fast_gen_obs, the default).

Usage: python benchmarks/bench_minigrid.py [--steps 102400] [--repeats 3]
"""

import argparse
import functools
import os
import sys
import time

import gymnasium as gym
import minigrid  # noqa: F401
import numpy as np
from minigrid.minigrid_env import MiniGridEnv
from minigrid.wrappers import ImgObsWrapper

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import REPO, print_table, run_script, ultho_on_off

sys.path.insert(0, REPO)
from ppo_ultho_minigrid import MINIGRID_GEN_OBS, fast_gen_obs


def env_only_steps_per_second(env_id: str, num_envs: int, steps: int, fast_obs: bool) -> float:
    MiniGridEnv.gen_obs = fast_gen_obs if fast_obs else MINIGRID_GEN_OBS
    envs = gym.vector.SyncVectorEnv(
        [functools.partial(lambda: ImgObsWrapper(gym.make(env_id))) for _ in range(num_envs)],
        autoreset_mode=gym.vector.AutoresetMode.SAME_STEP,
    )
    envs.reset(seed=list(range(num_envs)))
    actions = np.random.default_rng(0).integers(0, envs.single_action_space.n, (steps // num_envs, num_envs))
    start = time.perf_counter()
    for a in actions:
        envs.step(a)
    return len(actions) * num_envs / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="MiniGrid-DoorKey-6x6-v0")
    parser.add_argument("--steps", type=int, default=102_400, help="training steps per run (paper: 500K)")
    parser.add_argument("--repeats", type=int, default=3, help="rounds of the three alternating configurations")
    args = parser.parse_args()
    neutral = ["learning_rate=0.001", "minibatch_size=256", "vf_coef=0.5"]
    rows, shares = ultho_on_off("ppo_ultho_minigrid.py",
                                ["--env-id", args.env_id, "--total-timesteps", str(args.steps)],
                        neutral, args.repeats)
    rows["ULTHO, paper space, --no-fast-obs"] = [
        run_script("ppo_ultho_minigrid.py",
                   ["--env-id", args.env_id, "--total-timesteps", str(args.steps), "--no-fast-obs"])["sps"]
        for _ in range(args.repeats)]
    for name, fast_obs in (("env alone, MiniGrid's gen_obs", False), ("env alone, fast_gen_obs", True)):
        rows[name] = [env_only_steps_per_second(args.env_id, 16, 20_480, fast_obs) for _ in range(args.repeats)]
    print_table(f"ppo_ultho_minigrid.py on {args.env_id}, 16 envs x 128 steps", rows, shares)


if __name__ == "__main__":
    main()

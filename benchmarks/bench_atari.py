"""Throughput of ppo_ultho_atari.py at the paper's settings (8 envs x 128 steps, minibatch 256), ULTHO on and
off side by side, ULTHO's own cost, and the environment's own ceiling: ale-py's native vector environment
alone with the same preprocessing and 8 environments, stepped with random actions. Then float32 and bf16
(--precision) side by side, as plain PPO (--no-ultho) so that both do the same work: SPS, their ratio, peak
memory, and the shares of the wall time in the rollout and in the update (each run's summary.json).

Usage: python benchmarks/bench_atari.py [--env-id BattleZone] [--steps 10240] [--repeats 3] [--script-args ...]
"""

import argparse
import os
import sys
import time

import numpy as np
from ale_py.vector_env import AtariVectorEnv

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import precision_side_by_side, print_precision_table, print_table, ultho_on_off


def env_only_steps_per_second(game: str, num_envs: int, steps: int) -> float:
    # The same construction as the script's make_envs.
    envs = AtariVectorEnv(game, num_envs, autoreset_mode="SameStep", noop_max=30, repeat_action_probability=0.0,
                          episodic_life=False, reward_clipping=False, max_num_frames_per_episode=108_000)
    envs.reset(seed=np.arange(num_envs))
    actions = np.random.default_rng(0).integers(0, envs.single_action_space.n, (steps // num_envs, num_envs))
    start = time.perf_counter()
    for a in actions:
        envs.step(a)
    seconds = time.perf_counter() - start
    envs.close()
    return len(actions) * num_envs / seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env-id", default="BattleZone")
    parser.add_argument("--rom", default="battle_zone", help="the ROM id of --env-id, for the environment-only row")
    parser.add_argument("--steps", type=int, default=10_240, help="training steps per run (paper: 10M)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="rounds of alternating runs (the three ULTHO configurations, then the two precisions)")
    parser.add_argument("--script-args", nargs=argparse.REMAINDER, default=[],
                        help="further arguments for every training run (e.g. --torch-threads 2)")
    parser.add_argument("--sections", nargs="+", choices=("ultho", "precision"), default=["ultho", "precision"],
                        help="which tables: ULTHO on and off, float32 against bf16 (default both)")
    args = parser.parse_args()
    neutral = ["minibatch_size=256", "vf_coef=0.5", "ent_coef=0.01"]
    base = ["--env-id", args.env_id, "--total-timesteps", str(args.steps), *args.script_args]
    if "ultho" in args.sections:
        rows, shares = ultho_on_off("ppo_ultho_atari.py", base, neutral, args.repeats)
        rows["env alone (ceiling)"] = [env_only_steps_per_second(args.rom, 8, 20_480) for _ in range(args.repeats)]
        print_table(f"ppo_ultho_atari.py on {args.env_id}, 8 envs x 128 steps", rows, shares)
        print()

    if "precision" in args.sections:
        runs = precision_side_by_side("ppo_ultho_atari.py", [*base, "--no-ultho"], args.repeats)
        print_precision_table(f"ppo_ultho_atari.py --no-ultho on {args.env_id}, 8 envs x 128 steps, float32 vs bf16",
                              runs)


if __name__ == "__main__":
    main()

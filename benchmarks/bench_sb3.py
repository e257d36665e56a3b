"""Cost of ultho_sb3.ULTHOCallback: SB3 PPO's learn() time with and without it, side by side.

After one untimed warm-up run, three configurations run in turn, `--repeats` times each (alternating, so
drifting machine load hits all alike), each a fresh PPO with the same seed writing SB3's TensorBoard log:

* PPO: no callback.
* PPO + ULTHO, neutral space: every one of the eight clusters, each with PPO's own value as its only candidate.
  The training is identical to PPO's while the callback credits, selects, applies (recomputing GAE whenever it
  picks gae_lambda) and logs 8 clusters' tags every rollout: the difference is the callback's own cost.
* PPO + ULTHO, the README example's space: learning_rate 1e-4 / 3e-4 / 1e-3 and n_epochs 5 / 10 / 20. The choices change
  the work (20 epochs cost twice 10), so this row shows the effect of tuning, not overhead.

The table gives learn()'s wall time (median, min, max), the median's ratio to PPO's, and the share of each run's
wall time spent inside the callback (ULTHOCallback.seconds; SB3 writes the logged tags in its own dump, which
the ratio of the neutral row includes and this share does not).

Usage: python benchmarks/bench_sb3.py [--total-timesteps 65536] [--repeats 3] [--n-envs 8] [--n-steps 256]
"""

import argparse
import os
import statistics
import sys
import tempfile
import time

import torch

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from common import REPO, machine

sys.path.insert(0, REPO)
from ultho_sb3 import CLUSTERS, ULTHOCallback, setting_in_force  # before SB3: it quiets gym's import notice
from stable_baselines3 import PPO
from stable_baselines3.common.env_util import make_vec_env

TOOL = "bench_sb3"
EXAMPLE_SPACE = {"learning_rate": [1e-4, 3e-4, 1e-3], "n_epochs": [5, 10, 20]}


class Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        """Bad input: one line on stderr naming it, exit status 2."""
        print(f"{TOOL}: error: {message}", file=sys.stderr)
        sys.exit(2)


def positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if value <= 0:
        raise argparse.ArgumentTypeError(f"{text} must be positive")
    return value


def one_run(args: argparse.Namespace, space: str | None, logdir: str) -> tuple[float, float]:
    """(learn() wall time, seconds inside the callback) of one fresh PPO run."""
    model = PPO("MlpPolicy", make_vec_env(args.env_id, n_envs=args.n_envs, seed=0), n_steps=args.n_steps,
                batch_size=args.batch_size, seed=0, device="cpu", tensorboard_log=logdir)
    callback = None
    if space == "neutral":
        callback = ULTHOCallback({name: [setting_in_force(model, name)] for name in CLUSTERS})
    elif space == "example":
        callback = ULTHOCallback(EXAMPLE_SPACE)
    start = time.perf_counter()
    model.learn(args.total_timesteps, callback=callback)
    return time.perf_counter() - start, callback.seconds if callback is not None else 0.0


def main() -> None:
    parser = Parser(prog=TOOL, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--total-timesteps", type=positive_int, default=65_536, help="steps of each learn()")
    parser.add_argument("--repeats", type=positive_int, default=3, help="runs of each configuration")
    parser.add_argument("--env-id", default="CartPole-v1", help="a Gymnasium environment id")
    parser.add_argument("--n-envs", type=positive_int, default=8, help="environments in SB3's DummyVecEnv")
    parser.add_argument("--n-steps", type=positive_int, default=256, help="PPO's n_steps (rollout per environment)")
    parser.add_argument("--batch-size", type=positive_int, default=64, help="PPO's batch_size; must divide the rollout")
    parser.add_argument("--torch-threads", type=positive_int, default=1, help="CPU threads for torch")
    args = parser.parse_args()
    rollout = args.n_envs * args.n_steps
    if rollout % args.batch_size:
        parser.error(f"--batch-size {args.batch_size} does not divide the rollout of --n-envs * --n-steps = {rollout}")
    try:
        make_vec_env(args.env_id, n_envs=1).close()
    except Exception as err:  # noqa: BLE001  (gymnasium raises several types for an unknown or unusable id)
        parser.error(f"--env-id {args.env_id!r}: {err}")
    torch.set_num_threads(args.torch_threads)

    rows = {"PPO": None, "PPO + ULTHO, neutral space": "neutral", "PPO + ULTHO, the README example's space": "example"}
    seconds: dict[str, list[float]] = {row: [] for row in rows}
    shares: dict[str, list[float]] = {row: [] for row in rows}
    with tempfile.TemporaryDirectory() as logdir:
        one_run(args, None, logdir)  # untimed: the first run in a process pays one-off costs
        for _ in range(args.repeats):
            for row, space in rows.items():
                wall, inside = one_run(args, space, logdir)
                seconds[row].append(wall)
                shares[row].append(inside / wall)

    reference = statistics.median(seconds["PPO"])
    print(f"# SB3 PPO with and without ULTHOCallback  ({machine()}, torch threads {args.torch_threads})")
    print(f"{args.env_id}, {args.n_envs} envs x {args.n_steps} steps, batch {args.batch_size}, "
          f"{args.total_timesteps:,} steps per learn(), {args.repeats} alternating runs each, TensorBoard log on\n")
    print("| configuration | median learn() s | min | max | ratio to PPO | callback's share of wall time |")
    print("|---|---|---|---|---|---|")
    for row in rows:
        med = statistics.median(seconds[row])
        share = f"{100 * statistics.median(shares[row]):.3f}%" if rows[row] else "-"
        print(f"| {row} | {med:.2f} | {min(seconds[row]):.2f} | {max(seconds[row]):.2f} | {med / reference:.3f} "
              f"| {share} |")


if __name__ == "__main__":
    main()

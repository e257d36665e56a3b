"""How well each ULTHO variant chooses, on synthetic hierarchical bandits: regret and best-arm share.

Every problem has MiniGrid's shape (3 clusters x 3 values, 244 selections, one per PPO iteration) and draws
each value's effect from N(0, 1) per seed. Scenarios:

- stationary x S: a choice's credit is S * (its effect + N(0, 1) noise), for S = 0.01, 1, 100 (the credits'
  scale differs by benchmark: MiniGrid's values lie in [0, 1], PyBullet's normalized returns reach 100s);
- drifting: the effects are drawn anew halfway through;
- trend x S: like the critic's mean value V-bar during training. The utility measured after each choice is
  V(t+1) = V(t) + S * (1/244 + effect / 244 + N(0, 1) / 244): it rises by S over the run whatever is chosen,
  and each choice adds its effect. A level credit is V(t+1), an improvement credit V(t+1) - V(t).

Regret: the mean over pulls of (best effect - chosen effect), in units of the spread (standard deviation) of the
effects, so 0 is perfect (the first row, uniformly random choices, gives the other end); best: the share of pulls
on the best value. Means over --seeds seeds. Not a timing benchmark: it runs anywhere.

Usage: python benchmarks/bench_strategies.py [--seeds 50]
"""

import argparse
import os
import random
import statistics
import sys

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from ultho_bandit import ULTHO

CLUSTERS, VALUES, PULLS = 3, 3, 244
VARIANTS = [  # (label, options; None: a uniformly random cluster, then value)
    ("uniformly random choices", None),
    ("paper: ucb level none, c=5", dict(strategy="ucb", credit="level", scale="none", c=5.0)),
    ("ucb level none, c=1", dict(strategy="ucb", credit="level", scale="none", c=1.0)),
    ("ucb level running, c=5", dict(strategy="ucb", credit="level", scale="running", c=5.0)),
    ("ucb level running, c=1", dict(strategy="ucb", credit="level", scale="running", c=1.0)),
    ("ucb improvement none, c=5", dict(strategy="ucb", credit="improvement", scale="none", c=5.0)),
    ("ucb improvement running, c=5", dict(strategy="ucb", credit="improvement", scale="running", c=5.0)),
    ("ucb improvement running, c=1", dict(strategy="ucb", credit="improvement", scale="running", c=1.0)),
    ("ts level none", dict(strategy="ts", credit="level", scale="none")),
    ("ts level running", dict(strategy="ts", credit="level", scale="running")),
    ("ts improvement none", dict(strategy="ts", credit="improvement", scale="none")),
    ("ts improvement running", dict(strategy="ts", credit="improvement", scale="running")),
    ("exp3 level running", dict(strategy="exp3", credit="level", scale="running")),
    ("exp3 improvement none", dict(strategy="exp3", credit="improvement", scale="none")),
    ("exp3 improvement running", dict(strategy="exp3", credit="improvement", scale="running")),
]
SCENARIOS = [("stationary", 0.01), ("stationary", 1.0), ("stationary", 100.0), ("drifting", 1.0), ("trend", 1.0),
             ("trend", 100.0)]


def play(options: dict, scenario: str, scale: float, window: int, seed: int) -> tuple[float, float]:
    """(regret in units of the effects' spread, share of pulls on the best value) of one run."""
    rng = random.Random(seed)
    effects = [[rng.gauss(0.0, 1.0) for _ in range(VALUES)] for _ in range(CLUSTERS)]
    space = {f"k{k}": list(range(VALUES)) for k in range(CLUSTERS)}
    bandit = ULTHO(space, window=window, seed=seed, **(options or {}))
    chooser = random.Random(10_000 + seed)
    level, regret, best_pulls = 0.0, 0.0, 0
    for t in range(PULLS):
        if scenario == "drifting" and t == PULLS // 2:
            effects = [[rng.gauss(0.0, 1.0) for _ in range(VALUES)] for _ in range(CLUSTERS)]
        flat = [e for row in effects for e in row]
        spread = statistics.pstdev(flat)
        name, value = bandit.select(before=level)
        if options is None:
            name, value = f"k{chooser.randrange(CLUSTERS)}", chooser.randrange(VALUES)
        effect = effects[int(name[1:])][value]
        regret += (max(flat) - effect) / spread
        best_pulls += effect == max(flat)
        if scenario == "trend":
            level += scale * (1.0 + effect + rng.gauss(0.0, 1.0)) / PULLS
            bandit.update(level)
        else:
            level = scale * (effect + rng.gauss(0.0, 1.0))
            bandit.update(level)
    return regret / PULLS, best_pulls / PULLS


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=50, help="problems per cell (default 50)")
    parser.add_argument("--window", type=int, default=10, help="W of every variant (default 10, the paper's MiniGrid)")
    args = parser.parse_args()
    print(f"# ULTHO variants on synthetic 3x3 bandits, {PULLS} selections, W={args.window}, {args.seeds} seeds")
    print("# each cell: regret (effect spreads per pull) / share of pulls on the best value")
    header = [f"{name} x{scale:g}" for name, scale in SCENARIOS]
    print("| variant | " + " | ".join(header) + " |")
    print("|---|" + "---|" * len(header))
    for label, options in VARIANTS:
        cells = []
        for scenario, scale in SCENARIOS:
            results = [play(options, scenario, scale, args.window, seed) for seed in range(args.seeds)]
            regret = statistics.fmean(r for r, _ in results)
            best = statistics.fmean(b for _, b in results)
            cells.append(f"{regret:.2f} / {100 * best:.0f}%")
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()

"""Cost of one ULTHO decision: a select() + update() pair, in microseconds, for several search-space sizes.

Usage: python benchmarks/bench_bandit.py [--pairs 200000]
"""

import argparse
import os
import platform
import random
import sys
import timeit

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from ultho_bandit import ULTHO


def microseconds_per_pair(clusters: int, values: int, pairs: int, repeats: int = 5) -> tuple[float, float]:
    """Best and median over `repeats` of the mean time of one select()+update() pair."""
    space = {f"cluster{k}": [float(v + 1) for v in range(values)] for k in range(clusters)}
    rng = random.Random(0)
    utilities = [rng.gauss(0.0, 1.0) for _ in range(4096)]
    times = []
    for _ in range(repeats):
        bandit = ULTHO(space, c=5.0, window=10)
        it = iter(range(pairs))

        def pair(bandit: ULTHO = bandit, it=it) -> None:
            bandit.select()
            bandit.update(utilities[next(it) & 4095])

        times.append(timeit.timeit(pair, number=pairs) / pairs * 1e6)
    times.sort()
    return times[0], times[len(times) // 2]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--pairs", type=int, default=200_000, help="select()+update() pairs per measurement")
    args = parser.parse_args()
    print(f"# ULTHO select()+update() cost  ({platform.processor() or platform.machine()}, "
          f"{os.cpu_count()} cores, Python {platform.python_version()})")
    print("| clusters x values | best µs/pair | median µs/pair |")
    print("|---|---|---|")
    for clusters, values in [(1, 3), (3, 3), (4, 3), (5, 3), (4, 10)]:
        best, median = microseconds_per_pair(clusters, values, args.pairs)
        print(f"| {clusters} x {values} | {best:.2f} | {median:.2f} |")


if __name__ == "__main__":
    main()

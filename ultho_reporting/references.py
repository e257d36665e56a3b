"""The fixed reference scores that put each benchmark's returns on one scale.

A run's score is ``(R - low) / (high - low)`` with the (low, high) of its environment, constants that never
depend on which other runs a report holds, so adding a method or a failed run changes no score. The numbers
and their sources are in docs/paper.md's "Score normalization constants"; the ALE and Procgen scripts keep
copies of theirs (tests/test_reference_scores.py keeps all three equal). A new benchmark needs an entry in
``BENCHMARKS``, ``REFERENCES`` and ``NORMALIZATION``.
"""

import re

PROCGEN_EASY = {
    "bigfish": (1, 40), "bossfight": (0.5, 13), "caveflyer": (3.5, 12), "chaser": (0.5, 13),
    "climber": (2, 12.6), "coinrun": (5, 10), "dodgeball": (1.5, 19), "fruitbot": (-1.5, 32.4),
    "heist": (3.5, 10), "jumper": (3, 10), "leaper": (3, 10), "maze": (5, 10), "miner": (1.5, 13),
    "ninja": (3.5, 10), "plunder": (4.5, 30), "starpilot": (2.5, 64),
}
"""Procgen easy-mode (R_min, R_max), Cobbe et al. 2020 (docs/paper.md; ppo_ultho_procgen.py keeps a copy)."""

ALE_HUMAN = {
    "BattleZone": (2360.0, 37187.5), "DoubleDunk": (-18.6, -16.4), "NameThisGame": (2292.3, 8049.0),
    "Phoenix": (761.4, 7242.6), "Qbert": (163.9, 13455.0),
}
"""ALE (random, human) scores for human normalization (docs/paper.md; ppo_ultho_atari.py keeps a copy)."""

PYBULLET_REFERENCE = {
    "AntBulletEnv": (362.6, 2865.9), "HalfCheetahBulletEnv": (-1268.9, 2924.7),
    "HopperBulletEnv": (19.9, 2575.1), "Walker2DBulletEnv": (16.7, 2110.0),
}
"""PyBullet (uniform random policy, rl-baselines3-zoo's PPO after 2M steps) returns (docs/paper.md)."""

MINIGRID_RANGE = {"MiniGrid": (0.0, 1.0)}
"""MiniGrid's returns lie in [0, 1] (1 - 0.9 * steps / max_steps on success, else 0): used as they are."""

DMC_RANGE = {re.sub("[^a-z]", "", f"{domain}{task}".lower()): (0.0, 1000.0) for domain, tasks in {
    "acrobot": "swingup swingup_sparse", "ball_in_cup": "catch", "cheetah": "run", "dog": "stand walk trot run fetch",
    "cartpole": "balance balance_sparse swingup swingup_sparse two_poles three_poles",
    "finger": "spin turn_easy turn_hard", "fish": "upright swim", "hopper": "stand hop",
    "humanoid": "stand walk run run_pure_state", "humanoid_CMU": "stand walk run",
    "manipulator": "bring_ball bring_peg insert_ball insert_peg", "pendulum": "swingup", "point_mass": "easy hard",
    "quadruped": "walk run escape fetch", "reacher": "easy hard", "stacker": "stack_2 stack_4",
    "swimmer": "swimmer6 swimmer15", "walker": "stand walk run"}.items() for task in tasks.split()}
"""The DeepMind Control Suite's tasks (DOMAIN-TASK, by their letters): returns lie in [0, 1000] (a reward in
[0, 1] at each of 1000 steps), divided by 1000; not lqr, whose episodes never end and whose reward can be
negative. Keyed by task, not domain, so that gymnasium ids such as HalfCheetah-v5 or Pendulum-v1, which
sac_ultho_dmc.py also runs, get no DMC scale."""

BENCHMARKS = {"procgen": "Procgen", "atari": "ALE", "minigrid": "MiniGrid", "pybullet": "PyBullet", "dmc": "DMC"}
"""Each benchmark (``ppo_ultho_<benchmark>.py``, ``sac_ultho_dmc.py``) and its name in the report, in the
report's order."""

REFERENCES = {"procgen": PROCGEN_EASY, "atari": ALE_HUMAN, "pybullet": PYBULLET_REFERENCE,
              "minigrid": MINIGRID_RANGE, "dmc": DMC_RANGE}

NORMALIZATION = {
    "procgen": "Procgen easy-mode min-max normalized test score, (R - R_min) / (R_max - R_min) with Cobbe et al. "
               "2020's constants",
    "atari": "human-normalized score, (R - random) / (human - random)",
    "pybullet": "(R - random policy) / (rl-baselines3-zoo PPO - random policy), the references of docs/paper.md",
    "minigrid": "the final score as it is (MiniGrid's returns lie in [0, 1])",
    "dmc": "the final score / 1000 (DeepMind Control Suite returns lie in [0, 1000])",
}
"""How each benchmark's scores are normalized, in the words of the report and of aggregate.csv."""


def game_of(env_id: str, table: dict) -> str | None:
    """The table's game named in an environment id ("ALE/Qbert-v5", "procgen-bigfish-v0", ...)."""
    def alphanumeric(name: str) -> str:  # digits kept: Walker2DBulletEnv-v0 names Walker2DBulletEnv
        return re.sub("[^a-z0-9]", "", name.lower())

    return next((game for game in sorted(table, key=len, reverse=True)
                 if alphanumeric(game) in alphanumeric(env_id)), None)


def reference_of(benchmark: str, env_id: str) -> tuple[float, float] | None:
    """The fixed (low, high) reference scores of an environment: the score is (R - low) / (high - low)."""
    table = REFERENCES[benchmark]
    game = game_of(env_id, table)
    return None if game is None else table[game]


def normalized(benchmark: str, env_id: str, raw: float) -> float | None:
    """The score on the benchmark's fixed scale; None for an environment without reference scores."""
    reference = reference_of(benchmark, env_id)
    if reference is None:
        return None
    low, high = reference
    return (raw - low) / (high - low)

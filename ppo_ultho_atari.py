"""PPO with ULTHO hyperparameter optimization on the Arcade Learning Environment, in one file (CleanRL style).

Every PPO iteration the ULTHO bandit (``ultho_bandit.py``, Algorithm 1 of Yuan et al., ICCV 2025) picks one
hyperparameter cluster and one value in it, the value is applied (``settings.<name> = value``) for that
iteration's update, and the choice is credited with the critic's value estimate afterwards. ``--no-ultho``
is plain PPO with fixed settings, the paper's baseline.

Environment: ale-py's native vector environment (``ale_py.vector_env.AtariVectorEnv``), whose C++ threads do
the frame skip (4, max-pooled over the last two frames), the 84x84 grayscale resize, the 4-frame stack and up
to 30 no-op starts. Training treats a lost life as the end of an episode (CleanRL's EpisodicLifeEnv, without
resetting the game); rewards are normalized by the running standard deviation of the discounted return (the
paper's "reward normalization: yes"), not sign-clipped. Every return that is logged or scored is the
unclipped game score of a whole game (all lives).

Network: CleanRL's Nature CNN (three convolutions, a 512-unit layer, linear actor and critic heads), on the
observation divided by 255, in channels-last memory order (faster on the CPU, docs/atari.md). ``--precision bf16``
runs its convolutions and linear layers under bfloat16 autocast; its outputs, and all of PPO's arithmetic after
them, stay float32 (docs/precision.md).

Defaults are the paper's ALE settings (Appendix B, Tables 2-3; ``docs/paper.md``).

    python ppo_ultho_atari.py --env-id BattleZone --seed 1
    tensorboard --logdir runs
"""

import contextlib
import dataclasses
import importlib.util
import io
import json
import math
import netrc
import os
import random
import re
import resource
import secrets
import sys
import time
import urllib.parse
from collections import deque
from dataclasses import dataclass
from typing import Literal, Optional

import av
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
import tyro
from ale_py import roms
from ale_py.registration import rom_id_to_name
from ale_py.vector_env import AtariVectorEnv
from tensorboard.compat.proto.summary_pb2 import Summary
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from ultho_bandit import ULTHO, format_value, parse_clusters

SCRIPT = "ppo_ultho_atari"
CHECKPOINT_FORMAT = 1
VIDEO_FPS = 15
"""frames per second of --capture-video's MP4s: the emulator's 60 frames a second, every fourth (frameskip 4)"""

SEARCH_SPACE = {
    "minibatch_size": [128, 256, 512],
    "vf_coef": [0.25, 0.5, 1.0],
    "ent_coef": [0.01, 0.05, 0.1],
}
"""The paper's ALE search space (Table 2): a bare name in --ultho-clusters takes these values."""

TUNABLE = ("learning_rate", "minibatch_size", "vf_coef", "ent_coef", "update_epochs", "clip_coef", "max_grad_norm")
"""Settings a cluster may override; each is read afresh by every PPO update."""

HUMAN_NORMALIZATION = {
    "BattleZone": (2360.0, 37187.5),
    "DoubleDunk": (-18.6, -16.4),
    "NameThisGame": (2292.3, 8049.0),
    "Phoenix": (761.4, 7242.6),
    "Qbert": (163.9, 13455.0),
}
"""(random, human) scores of the ALE-5 games (docs/paper.md): human-normalized = (R - random) / (human - random).
The same as ultho_reporting/references.py's ALE_HUMAN (tests/test_reference_scores.py checks; this file stays
self-contained)."""

REWARD_CLIP = 10.0
"""Normalized rewards are clipped to [-10, 10], as in CleanRL's normalized-reward PPO scripts."""


@dataclass
class Args:
    exp_name: str = SCRIPT
    """the name of this experiment (part of the default run name)"""
    seed: int = 1
    """seed of the experiment (Python, NumPy, torch and the environments)"""
    torch_deterministic: bool = True
    """if toggled, `torch.backends.cudnn.deterministic=True`"""
    cuda: bool = True
    """if toggled, use CUDA when it is available"""
    torch_threads: int = 0
    """CPU threads for torch (0: one per core, torch's own default); set 1 when other jobs share the cores
    (docs/atari.md has the measurements)"""
    precision: Literal["float32", "bf16"] = "float32"
    """float32 (the paper's) or bf16: the network's convolutions and linear layers under bfloat16 autocast, on
    the CPU (AVX512-BF16 or AMX) or CUDA; weights, optimizer, log-probabilities, ratio and losses stay float32
    (docs/precision.md). A resumed run keeps its own"""
    run_name: Optional[str] = None
    """name of the run directory under --runs-dir (default: {env_id}__{exp_name}__{seed}__{unix time})"""
    runs_dir: str = "runs"
    """directory that holds the run directories"""

    # Environment and PPO (paper Appendix B, ALE column)
    env_id: str = "BattleZone"
    """an ALE game: its name (BattleZone), ROM id (battle_zone), or a Gymnasium id (ALE/BattleZone-v5,
    BattleZoneNoFrameskip-v4)"""
    total_timesteps: int = 10_000_000
    """total environment steps of the run (agent steps; each is 4 emulator frames)"""
    learning_rate: float = 2.5e-4
    """Adam learning rate (no annealing: ULTHO may set it)"""
    num_envs: int = 8
    """number of parallel environments"""
    num_steps: int = 128
    """steps per environment per rollout"""
    gamma: float = 0.99
    """discount factor"""
    gae_lambda: float = 0.95
    """lambda of generalized advantage estimation"""
    minibatch_size: int = 256
    """samples per minibatch (the paper's "batch size"); must divide num_envs * num_steps"""
    update_epochs: int = 4
    """epochs over the rollout per update (CleanRL's value for ALE; the paper's table leaves it out)"""
    norm_adv: bool = True
    """normalize advantages per minibatch"""
    clip_coef: float = 0.2
    """policy and value clipping coefficient (the paper's value clip range 0.2; CleanRL's ppo_atari uses 0.1)"""
    clip_vloss: bool = True
    """clip the value loss with clip_coef (the paper's value clip range 0.2)"""
    ent_coef: float = 0.01
    """entropy coefficient"""
    vf_coef: float = 0.5
    """value loss coefficient"""
    max_grad_norm: float = 0.5
    """maximum norm for gradient clipping"""
    target_kl: Optional[float] = None
    """stop an update's epochs early once the approximate KL exceeds this (off by default)"""
    repeat_action_probability: float = 0.0
    """sticky actions: the chance that the emulator repeats the previous action (0 as in CleanRL and envpool;
    Machado et al. 2018 recommend 0.25)"""
    noop_max: int = 30
    """at most this many random no-op actions start every game"""
    episodic_life: bool = True
    """train with a lost life as the end of an episode (the game goes on; scores count whole games)"""
    env_threads: int = 0
    """threads of the native vector environment (0: ale-py's default)"""

    # ULTHO
    ultho: bool = True
    """tune hyperparameters with ULTHO; --no-ultho runs plain PPO with fixed settings"""
    ultho_c: float = 5.0
    """exploration coefficient c of Eqs. 4-5 (paper grid: 1, 5)"""
    ultho_window: int = 10
    """window W of the utility's moving average, Eq. 6 (paper grid: 10, 50, 100)"""
    ultho_clusters: tuple[str, ...] = tuple(SEARCH_SPACE)
    """search space: NAME takes the paper's values, NAME=V1,V2,... sets them; one cluster = a Relay run"""
    ultho_utility: Literal["value", "return", "value-after", "authors-return"] = "value"
    """credit: mean critic value over the next rollout, mean GAE return over it, the updated critic on this
    rollout's observations (the paper's Algorithm 1 read literally), or the authors' public code's credit: the
    mean GAE return of the rollout just collected, given to the choice made for its own update (never the run's
    first choice); docs/bandit.md#the-utility-signal"""
    ultho_strategy: Literal["ucb", "ts", "exp3", "round-robin"] = "ucb"
    """how the bandit chooses at both levels: ucb (Eqs. 4-5, the paper's), ts (Gaussian Thompson sampling),
    exp3 (discounted Exp3) or round-robin (the values in turn, the control without a bandit);
    docs/strategies.md says when to use which"""
    ultho_credit: Literal["level", "improvement"] = "level"
    """what a choice is credited with: the utility as measured (level, the paper's) or its change since
    just before the choice took effect (improvement)"""
    ultho_scale: Literal["none", "running"] = "none"
    """none (the paper's) or running: utilities in units of the credits' running standard deviation, so c
    means the same whatever the benchmark's value scale"""
    ultho_exp3_eta: float = 0.5
    """Exp3's learning rate (with --ultho-strategy exp3)"""

    # Evaluation, checkpoints, output
    eval_episodes: int = 10
    """whole games of the final policy on fresh environments for summary.json (0: skip)"""
    checkpoint_every: int = 50
    """iterations between checkpoints (one is also written at the end)"""
    resume: Optional[str] = None
    """run directory to continue to its --total-timesteps; its checkpoint's settings are used"""
    init_from: Optional[str] = None
    """run directory whose checkpoint this run starts from: network, optimizer state, reward normalization, the
    games in progress and counters are taken from it, every setting from this command line (docs/hpo_baselines.md)"""
    quiet: bool = False
    """print nothing but errors"""

    # Tracking, videos, evaluating a finished run (docs/scripts.md#tracking-videos-and-evaluation)
    track: bool = False
    """mirror the run to Weights & Biases: its config, its code and every TensorBoard scalar (WANDB_MODE=offline
    logs locally, for `wandb sync` later)"""
    wandb_project_name: str = "ultho"
    """the W&B project of --track"""
    wandb_entity: Optional[str] = None
    """the W&B team or user of --track (default: your W&B default entity)"""
    wandb_group: Optional[str] = None
    """the W&B group of --track (sweep.py, relay_ultho.py and hpo_baselines.py group a study's runs by it)"""
    capture_video: bool = False
    """record the first episode of the final evaluation as an MP4 under runs/<run>/videos/ (with --evaluate, the
    first episode it runs)"""
    video_every: int = 0
    """with --capture-video, also record one evaluation episode every this many iterations (0: the final one only)"""
    evaluate: Optional[str] = None
    """run directory of this script to evaluate instead of training: its checkpoint's policy plays --eval-episodes
    episodes on the final evaluation's environment seeds; prints mean and std, writes nothing but
    --capture-video's MP4"""

    def __post_init__(self) -> None:
        if self.run_name is None:  # resolved once, when the command line is parsed: every later use agrees
            self.run_name = f"{self.env_id}__{self.exp_name}__{self.seed}__{int(time.time())}"


@dataclass
class Settings:
    """The settings in force: the TUNABLE ones, which ULTHO changes one at a time and every PPO update reads
    afresh. They start as the command line's (``args`` itself is never changed), are saved in the checkpoint
    and are summary.json's ``settings_in_force``."""

    learning_rate: float
    minibatch_size: int
    vf_coef: float
    ent_coef: float
    update_epochs: int
    clip_coef: float
    max_grad_norm: float

    @classmethod
    def from_args(cls, args: Args) -> "Settings":
        return cls(**{name: getattr(args, name) for name in TUNABLE})


GAMES = {rom_id_to_name(rom): rom for rom in roms.get_all_rom_ids()}
"""Every ALE game that ships with ale-py: name (BattleZone) -> ROM id (battle_zone)."""


def game_name(env_id: str) -> str | None:
    """The game's name (BattleZone) for its name, ROM id or Gymnasium id; None for no such game."""
    name = re.sub(r"^ALE/|(NoFrameskip|Deterministic)?-v\d+$", "", env_id)
    if name in GAMES:
        return name
    return next((n for n, rom in GAMES.items() if rom == name), None)


def game_rom(env_id: str) -> str | None:
    name = game_name(env_id)
    return None if name is None else GAMES[name]


def make_envs(args: Args, num_envs: int, screen: bool = False) -> AtariVectorEnv:
    # The emulator's rewards come back unclipped and its episodes are whole games: the loop derives life
    # losses and normalizes rewards itself, so it can score games by their real score. SameStep autoreset: a
    # finished game's next observation is already the new game's first, as CleanRL's PPO assumes (training
    # then resets that environment again with a seed of its own, see game_seeds). Games are cut at 108,000
    # frames (30 minutes), the usual limit. screen=True: the same games, observed as the full colour screen
    # (--capture-video's frames) instead of the agent's 84x84 grayscale stack.
    return AtariVectorEnv(
        game_rom(args.env_id), num_envs, num_threads=args.env_threads, autoreset_mode="SameStep",
        frameskip=4, maxpool=True, img_height=210 if screen else 84, img_width=160 if screen else 84,
        grayscale=not screen, stack_num=1 if screen else 4,
        noop_max=args.noop_max, repeat_action_probability=args.repeat_action_probability, use_fire_reset=True,
        episodic_life=False, reward_clipping=False, max_num_frames_per_episode=108_000,
    )


def game_seeds(seed: int, env_indices: np.ndarray, game_numbers: np.ndarray) -> np.ndarray:
    """Reset seeds of the given games: game g of environment e starts from a seed fixed by (seed, e, g), so
    that a game in progress is determined by its seed and its actions."""
    return np.array([np.random.SeedSequence([seed, e, g]).generate_state(1)[0] >> 1
                     for e, g in zip(env_indices, game_numbers)], dtype=np.int64)


# The environment index of the evaluation games in game_seeds' key: no training environment has it, so an
# evaluation game is never a training game, and runs with neighbouring seeds share none.
EVAL_ENV = 2**32 - 1


def replay(envs: AtariVectorEnv, seeds: np.ndarray, histories: list[np.ndarray]) -> tuple[np.ndarray, dict]:
    """Rebuilds every environment's game in progress, since the native environment's state cannot be saved:
    each game restarts from its seed and repeats its actions. The restarts are staggered so that every replay
    ends at the same step; an environment waiting for its restart idles with no-ops."""
    lengths = np.array([len(h) for h in histories])
    offsets = lengths.max() - lengths
    obs, info = envs.reset(seed=seeds)  # the longest games start now, the others again later
    for t in range(lengths.max()):
        actions = np.zeros(len(histories), dtype=np.int64)
        for k in np.flatnonzero(offsets <= t):
            actions[k] = histories[k][t - offsets[k]]
        obs, _, _, _, info = envs.step(actions)
        starting = offsets == t + 1
        if starting.any():
            obs, info = envs.reset(seed=seeds[starting], options={"reset_mask": starting})
    return obs, info


class RunningMeanStd:
    """Running mean and variance of everything passed to update() (Chan et al.'s parallel formula), as in
    gymnasium's NormalizeReward."""

    def __init__(self) -> None:
        self.mean, self.var, self.count = 0.0, 1.0, 1e-4

    def update(self, x: np.ndarray) -> None:
        batch_mean, batch_var, n = float(x.mean()), float(x.var()), x.size
        delta, total = batch_mean - self.mean, self.count + n
        self.mean += delta * n / total
        self.var = (self.var * self.count + batch_var * n + delta ** 2 * self.count * n / total) / total
        self.count = total


def layer_init(layer: nn.Module, std: float = np.sqrt(2), bias_const: float = 0.0) -> nn.Module:
    torch.nn.init.orthogonal_(layer.weight, std)
    torch.nn.init.constant_(layer.bias, bias_const)
    return layer


class Agent(nn.Module):
    """The Nature CNN with a shared torso, as in CleanRL's ppo_atari."""

    def __init__(self, num_actions: int, precision: str):
        super().__init__()
        self.precision = precision  # not part of the state: a checkpoint loads into either precision
        self.network = nn.Sequential(
            layer_init(nn.Conv2d(4, 32, 8, stride=4)), nn.ReLU(),
            layer_init(nn.Conv2d(32, 64, 4, stride=2)), nn.ReLU(),
            layer_init(nn.Conv2d(64, 64, 3, stride=1)), nn.ReLU(),
            nn.Flatten(),
            layer_init(nn.Linear(64 * 7 * 7, 512)), nn.ReLU(),
        )
        self.actor = layer_init(nn.Linear(512, num_actions), std=0.01)
        self.critic = layer_init(nn.Linear(512, 1), std=1)
        # Channels-last convolutions are faster on the CPU (docs/atari.md, Speed).
        self.to(memory_format=torch.channels_last)

    def features(self, obs: torch.Tensor) -> torch.Tensor:
        # Reordered while still uint8 (a quarter of the bytes), then converted in place.
        return self.network(obs.contiguous(memory_format=torch.channels_last).float().div_(255.0))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """uint8 observations (N, 4, 84, 84) -> (action log-probabilities (N, A), values (N,)), both float32."""
        with torch.autocast(obs.device.type, dtype=torch.bfloat16, enabled=self.precision == "bf16"):
            hidden = self.features(obs)
            logits, value = self.actor(hidden), self.critic(hidden)
        # Outside autocast and in float32: the log-softmax, and all of PPO's arithmetic on what it returns.
        return F.log_softmax(logits.float(), dim=-1), value.float().squeeze(-1)

    def get_value(self, obs: torch.Tensor) -> torch.Tensor:
        with torch.autocast(obs.device.type, dtype=torch.bfloat16, enabled=self.precision == "bf16"):
            value = self.critic(self.features(obs))
        return value.float().squeeze(-1)


def sample(log_probs: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """One action per row. argmax(p / E) with E ~ Exp(1) is an exact categorical sample (the exponential
    race) and costs less than half of torch.multinomial on these tiny batches."""
    return (log_probs.exp() / torch.empty_like(log_probs).exponential_(generator=generator)).argmax(-1)


def ppo_loss(agent: Agent, args: Args, settings: Settings, obs: torch.Tensor, actions: torch.Tensor,
             old_logprobs: torch.Tensor, advantages: torch.Tensor, returns: torch.Tensor,
             old_values: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """PPO's clipped loss on these samples (advantages as the update uses them) and its statistics: policy loss,
    value loss, entropy, old approximate KL, approximate KL, clip fraction."""
    new_log_probs, newvalue = agent(obs)
    newlogprob = new_log_probs.gather(1, actions.unsqueeze(1)).squeeze(1)
    entropy = -(new_log_probs.exp() * new_log_probs).sum(-1)
    logratio = newlogprob - old_logprobs
    ratio = logratio.exp()
    with torch.no_grad():
        old_approx_kl = (-logratio).mean()
        approx_kl = ((ratio - 1) - logratio).mean()
        clipfrac = ((ratio - 1.0).abs() > settings.clip_coef).float().mean()

    pg_loss1 = -advantages * ratio
    pg_loss2 = -advantages * torch.clamp(ratio, 1 - settings.clip_coef, 1 + settings.clip_coef)
    pg_loss = torch.max(pg_loss1, pg_loss2).mean()

    if args.clip_vloss:
        v_loss_unclipped = (newvalue - returns) ** 2
        v_clipped = old_values + torch.clamp(newvalue - old_values, -settings.clip_coef, settings.clip_coef)
        v_loss = 0.5 * torch.max(v_loss_unclipped, (v_clipped - returns) ** 2).mean()
    else:
        v_loss = 0.5 * ((newvalue - returns) ** 2).mean()
    entropy_loss = entropy.mean()
    loss = pg_loss - settings.ent_coef * entropy_loss + v_loss * settings.vf_coef
    return loss, torch.stack([pg_loss, v_loss, entropy_loss, old_approx_kl, approx_kl, clipfrac]).detach()


def main(args: Args) -> None:
    space, checkpoint = validate(args)  # nothing is written or started before this returns
    if args.evaluate is not None:  # a finished run's policy, not a training run
        evaluate_run(evaluated_args(args, checkpoint), checkpoint)
        return
    resumed = args.resume is not None
    if resumed:  # the run goes on with its own arguments
        args = resumed_args(args, checkpoint)

    batch_size = args.num_envs * args.num_steps
    num_iterations = args.total_timesteps // batch_size
    # The run's settings before ULTHO changes any; a resumed run keeps its original ones.
    config = checkpoint["config"] if resumed else dataclasses.asdict(args)
    run_dir = args.resume if resumed else os.path.join(args.runs_dir, args.run_name)
    checkpoint_path = os.path.join(run_dir, "checkpoint.pt")

    random.seed(args.seed)
    np.random.seed(args.seed)
    torch.manual_seed(args.seed)
    torch.backends.cudnn.deterministic = args.torch_deterministic
    if args.torch_threads > 0:  # 0: torch's own default, one thread per core
        torch.set_num_threads(args.torch_threads)
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")
    minibatch_rng = np.random.default_rng(args.seed)

    bandit = ULTHO(space, c=args.ultho_c, window=args.ultho_window, strategy=args.ultho_strategy,
                   credit=args.ultho_credit, scale=args.ultho_scale, seed=args.seed,
                   exp3_eta=args.ultho_exp3_eta) if args.ultho else None
    tuned = list(space) if space is not None else list(SEARCH_SPACE)
    settings = Settings.from_args(args)  # the settings in force, which ULTHO changes

    envs = make_envs(args, args.num_envs)
    agent = Agent(envs.single_action_space.n, args.precision).to(device)
    optimizer = torch.optim.Adam(agent.parameters(), lr=settings.learning_rate, eps=1e-5, fused=True)

    start_iteration, global_step, elapsed_before = 1, 0, 0.0
    ultho_seconds = 0.0  # wall time spent on ULTHO's own work, reported as its share of the run
    rollout_seconds, update_seconds = 0.0, 0.0  # wall time of acting and stepping, and of the PPO update
    return_rms = RunningMeanStd()  # of the discounted return, whose scale normalizes the rewards
    recent_returns: deque[float] = deque(maxlen=100)
    recent_lengths: deque[int] = deque(maxlen=100)
    if checkpoint is not None:  # --resume or --init-from: go on from the checkpoint
        settings = restore(checkpoint, args, settings, agent, optimizer, bandit, minibatch_rng, device)
        start_iteration, global_step = checkpoint["iteration"] + 1, checkpoint["global_step"]
        elapsed_before, ultho_seconds = checkpoint["elapsed"], checkpoint["ultho_seconds"]
        # A checkpoint without the phase timings starts them from zero.
        rollout_seconds, update_seconds = checkpoint.get("rollout_seconds", 0.0), checkpoint.get("update_seconds", 0.0)
        return_rms.__dict__.update(checkpoint["return_rms"])
        recent_returns.extend(checkpoint["recent_returns"])
        recent_lengths.extend(checkpoint["recent_lengths"])

    # Every game starts from its own seed and its actions are kept until it ends: a resumed run replays the
    # games in progress at the checkpoint and goes on exactly as an uninterrupted run.
    env_indices = np.arange(args.num_envs)
    if checkpoint is None:
        games_started = np.zeros(args.num_envs, dtype=np.int64)
        seeds = game_seeds(args.seed, env_indices, games_started)
        histories: list[list[int]] = [[] for _ in env_indices]
        next_obs_np, info = envs.reset(seed=seeds)
        next_done_np = np.zeros(args.num_envs, dtype=bool)
        game_return = np.zeros(args.num_envs)  # unclipped score of the game in progress
        game_length = np.zeros(args.num_envs, dtype=np.int64)
        discounted_return = np.zeros(args.num_envs)  # per training episode, for the reward normalization
    else:
        games = checkpoint["games"]
        games_started, seeds = games["started"], games["seeds"]
        histories = [h.tolist() for h in games["actions"]]
        next_obs_np, info = replay(envs, seeds, games["actions"])
        if not np.array_equal(next_obs_np, games["next_obs"]):
            raise RuntimeError("replaying the games in progress did not reproduce the checkpoint's observations")
        next_done_np, discounted_return = games["next_done"], games["discounted_return"]
        game_return, game_length = games["return"], games["length"]
    lives = info["lives"]

    tracker = start_tracking(args, run_dir, config)  # before the writer: W&B syncs the scalars it writes
    writer = open_run_dir(run_dir, config, checkpoint, resumed)

    # Rollout storage: observations stay uint8, the network converts them per batch.
    obs = torch.zeros((args.num_steps, args.num_envs) + envs.single_observation_space.shape, dtype=torch.uint8,
                      device=device)
    actions = torch.zeros((args.num_steps, args.num_envs), dtype=torch.long, device=device)
    logprobs = torch.zeros((args.num_steps, args.num_envs), device=device)
    values = torch.zeros((args.num_steps, args.num_envs), device=device)
    rewards = np.zeros((args.num_steps, args.num_envs), dtype=np.float32)
    dones = np.zeros((args.num_steps, args.num_envs), dtype=np.float32)

    progress = tqdm(total=args.total_timesteps, initial=global_step, unit="step", dynamic_ncols=True,
                    disable=args.quiet or not sys.stderr.isatty())
    start_time, start_step = time.time(), global_step
    diverged = None  # where the run stopped with non-finite numbers, if it did
    for iteration in range(start_iteration, num_iterations + 1):
        # 1. Collect a rollout with the current policy.
        rollout_start = time.perf_counter()
        iteration_returns: list[float] = []
        iteration_lengths: list[int] = []
        for step in range(args.num_steps):
            global_step += args.num_envs
            next_obs = torch.from_numpy(next_obs_np).to(device)
            obs[step] = next_obs
            dones[step] = next_done_np
            with torch.no_grad():
                log_probs, value = agent(next_obs)
                action = sample(log_probs)
            actions[step] = action
            logprobs[step] = log_probs.gather(1, action.unsqueeze(1)).squeeze(1)
            values[step] = value
            action_np = action.cpu().numpy()
            for history, a in zip(histories, action_np.tolist()):
                history.append(a)
            next_obs_np, score, terminated, truncated, info = envs.step(action_np)
            game_over = terminated | truncated
            if game_over.any():
                # Restart the finished games from seeds of our own instead of the automatic reset's.
                games_started += game_over
                seeds[game_over] = game_seeds(args.seed, env_indices[game_over], games_started[game_over])
                for k in np.flatnonzero(game_over):
                    histories[k].clear()
                next_obs_np, info = envs.reset(seed=seeds[game_over], options={"reset_mask": game_over})
            # A new game reports full lives, so only a loss within a game counts.
            life_lost = info["lives"] < lives
            lives = info["lives"]
            next_done_np = game_over | life_lost if args.episodic_life else game_over
            discounted_return = discounted_return * args.gamma + score
            return_rms.update(discounted_return)
            rewards[step] = np.clip(score / np.sqrt(return_rms.var + 1e-8), -REWARD_CLIP, REWARD_CLIP)
            discounted_return[next_done_np] = 0.0
            game_return += score
            game_length += 1
            if game_over.any():
                finished = np.flatnonzero(game_over)
                iteration_returns += game_return[finished].tolist()
                iteration_lengths += game_length[finished].tolist()
                game_return[finished] = 0.0
                game_length[finished] = 0
        recent_returns.extend(iteration_returns)
        recent_lengths.extend(iteration_lengths)
        rollout_seconds += time.perf_counter() - rollout_start

        # 2. Generalized advantage estimation.
        with torch.no_grad():
            next_value = agent.get_value(torch.from_numpy(next_obs_np).to(device))
            rewards_t = torch.from_numpy(rewards).to(device)
            dones_t = torch.from_numpy(dones).to(device)
            next_done_t = torch.from_numpy(next_done_np.astype(np.float32)).to(device)
            advantages = torch.zeros_like(rewards_t)
            lastgaelam = torch.zeros(args.num_envs, device=device)
            for t in reversed(range(args.num_steps)):
                if t == args.num_steps - 1:
                    nextnonterminal, nextvalues = 1.0 - next_done_t, next_value
                else:
                    nextnonterminal, nextvalues = 1.0 - dones_t[t + 1], values[t + 1]
                delta = rewards_t[t] + args.gamma * nextvalues * nextnonterminal - values[t]
                lastgaelam = delta + args.gamma * args.gae_lambda * nextnonterminal * lastgaelam
                advantages[t] = lastgaelam
            returns = advantages + values

        # 3. ULTHO: credit the previous choice with what the updated policy collected, then choose anew.
        credit = None
        if bandit is not None:
            tick = time.perf_counter()
            # What is measured now, before this iteration's choice takes effect: it credits the previous choice
            # and is the baseline of --ultho-credit improvement (value-after credits after the update instead;
            # authors-return credits the choice made now, as the authors' code does, except the run's first).
            measured = (returns if args.ultho_utility in ("return", "authors-return") else values).mean().item()
            if bandit.pending is not None and args.ultho_utility in ("value", "return"):
                credit = measured
                bandit.update(credit)
            cluster, choice = bandit.select(before=measured)
            if args.ultho_utility == "authors-return":
                if iteration == 1:
                    bandit.withdraw()
                else:
                    credit = measured
                    bandit.update(credit)
            setattr(settings, cluster, choice)
            if cluster == "learning_rate":
                for group in optimizer.param_groups:
                    group["lr"] = choice
            ultho_seconds += time.perf_counter() - tick

        # 4. PPO update with the settings in force.
        update_start = time.perf_counter()
        b_obs = obs.reshape((-1,) + envs.single_observation_space.shape)
        b_logprobs, b_actions = logprobs.reshape(-1), actions.reshape(-1)
        b_advantages, b_returns, b_values = advantages.reshape(-1), returns.reshape(-1), values.reshape(-1)
        loss_sums = torch.zeros(6, device=device)  # policy, value, entropy, old kl, kl, clipfrac
        num_minibatches = 0
        for epoch in range(settings.update_epochs):
            permutation = torch.from_numpy(minibatch_rng.permutation(batch_size)).to(device)
            for start in range(0, batch_size, settings.minibatch_size):
                mb = permutation[start:start + settings.minibatch_size]
                mb_advantages = b_advantages[mb]
                if args.norm_adv:
                    mb_advantages = (mb_advantages - mb_advantages.mean()) / (mb_advantages.std() + 1e-8)
                loss, stats = ppo_loss(agent, args, settings, b_obs[mb], b_actions[mb], b_logprobs[mb], mb_advantages,
                                       b_returns[mb], b_values[mb])
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                nn.utils.clip_grad_norm_(agent.parameters(), settings.max_grad_norm)
                optimizer.step()
                loss_sums += stats
                num_minibatches += 1
            if args.target_kl is not None and stats[4].item() > args.target_kl:  # the last minibatch's approx KL
                break
        losses = (loss_sums / num_minibatches).tolist()
        update_seconds += time.perf_counter() - update_start
        if not all(map(math.isfinite, losses[:3])):  # policy, value, entropy
            # The weights are no longer finite: the run ends here, summary.json records where, and the
            # last good checkpoint stays as it was.
            diverged = {"what": "loss", "iteration": iteration, "global_step": global_step}
            break

        if bandit is not None and args.ultho_utility == "value-after":
            tick = time.perf_counter()
            with torch.no_grad():
                credit = torch.cat([agent.get_value(chunk) for chunk in b_obs.split(4096)]).mean().item()
            bandit.update(credit)
            ultho_seconds += time.perf_counter() - tick

        # 5. Log and checkpoint.
        elapsed = time.time() - start_time
        sps = int((global_step - start_step) / elapsed) if elapsed > 0 else 0
        log_iteration(writer, global_step, iteration_returns, iteration_lengths, optimizer.param_groups[0]["lr"], sps,
                      losses, b_returns, b_values, settings, tuned)
        if bandit is not None:
            tick = time.perf_counter()
            log_bandit(writer, bandit, credit, global_step)
            ultho_seconds += time.perf_counter() - tick
        report_progress(progress, args, iteration, num_iterations, global_step, sps, recent_returns,
                        f"{cluster}={format_value(choice)}" if bandit is not None else "fixed")
        if args.video_every and iteration % args.video_every == 0 and iteration != num_iterations:
            path = video_path(run_dir, f"iteration{iteration}", global_step)
            evaluate(agent, dataclasses.replace(args, eval_episodes=1), device, path)
            log_video(tracker, path)
        if iteration % args.checkpoint_every == 0 or iteration == num_iterations:
            writer.flush()  # the events up to the checkpoint reach the disk first: a kill after it must not lose them
            save_checkpoint(checkpoint_path, {
                "script": SCRIPT, "format": CHECKPOINT_FORMAT, "config": config,
                "settings": dataclasses.asdict(settings), "iteration": iteration, "global_step": global_step,
                "elapsed": elapsed_before + time.time() - start_time,
                "ultho_seconds": ultho_seconds, "rollout_seconds": rollout_seconds, "update_seconds": update_seconds,
                "agent": agent.state_dict(), "optimizer": optimizer.state_dict(),
                "bandit": bandit.state_dict() if bandit is not None else None,
                "return_rms": dict(return_rms.__dict__),
                "games": {"started": games_started, "seeds": seeds,
                          "actions": [np.array(h, dtype=np.uint8) for h in histories],
                          "next_obs": next_obs_np, "next_done": next_done_np, "discounted_return": discounted_return,
                          "return": game_return, "length": game_length},
                "recent_returns": list(recent_returns), "recent_lengths": list(recent_lengths),
                "rng": rng_state(device, minibatch_rng),
            })
    progress.close()
    envs.close()

    wall_time = elapsed_before + time.time() - start_time
    final_video = video_path(run_dir, "final", global_step) if args.capture_video and diverged is None else None
    eval_returns = evaluate(agent, args, device, final_video) if args.eval_episodes > 0 and diverged is None else []
    if eval_returns:
        writer.add_scalar("eval/return", float(np.mean(eval_returns)), global_step)
    writer.close()
    log_video(tracker, final_video)
    stop_tracking(tracker, diverged)
    write_summary(run_dir, args, config, settings, tuned, bandit, global_step,
                  num_iterations if diverged is None else diverged["iteration"], wall_time,
                  ultho_seconds, rollout_seconds, update_seconds, device, recent_returns, recent_lengths,
                  eval_returns, diverged)
    if diverged is not None:
        stop_non_finite(diverged, settings, tuned, checkpoint_path)


def evaluate(agent: Agent, args: Args, device: torch.device, video_path: Optional[str] = None) -> list[float]:
    """Unclipped scores of --eval-episodes whole games (seeds unused in training), one per environment,
    sampling the policy as in training from a generator of its own (evaluating changes nothing in training, and
    --evaluate repeats it exactly). With video_path, the first game is recorded there in colour: a second
    emulator that shows the full screen plays it alongside, with its seed and its actions (which determine it)."""
    generator = torch.Generator(device=device)
    generator.manual_seed(int(np.random.SeedSequence([args.seed, EVAL_ENV]).generate_state(1)[0]))
    returns: list[float] = []
    while len(returns) < args.eval_episodes:
        n = min(args.eval_episodes - len(returns), 64)
        seeds = game_seeds(args.seed, np.full(n, EVAL_ENV), np.arange(len(returns), len(returns) + n))
        envs = make_envs(args, n)
        obs, _ = envs.reset(seed=seeds)
        screen_env = make_envs(args, 1, screen=True) if video_path is not None and not returns else None
        frames: list[np.ndarray] = []
        if screen_env is not None:
            screen, _ = screen_env.reset(seed=seeds[:1])
        total, running = np.zeros(n), np.ones(n, dtype=bool)
        while running.any():
            with torch.no_grad():
                log_probs, _ = agent(torch.from_numpy(obs).to(device))
            action = sample(log_probs, generator).cpu().numpy()
            if screen_env is not None and running[0]:
                frames.append(screen[0, -1])
                screen, *_ = screen_env.step(action[:1])
            obs, reward, terminated, truncated, _ = envs.step(action)
            total += reward * running
            running &= ~(terminated | truncated)
        envs.close()
        if screen_env is not None:
            screen_env.close()
            write_video(video_path, frames, VIDEO_FPS)
        returns += total.tolist()
    return returns


def evaluate_run(args: Args, checkpoint: dict) -> None:
    """--evaluate: the policy of the run's checkpoint on the final evaluation's games, reported on stdout."""
    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")
    envs = make_envs(args, 1)
    agent = Agent(envs.single_action_space.n, args.precision).to(device)
    envs.close()
    agent.load_state_dict(checkpoint["agent"])
    path = video_path(args.evaluate, "evaluate", checkpoint["global_step"]) if args.capture_video else None
    report_evaluation(args, checkpoint, evaluate(agent, args, device, path), path)


# ---- Bookkeeping: input, checkpoints, logging, summary (not the algorithm) ----
class UsageError(Exception):
    """Bad input: reported as one line on stderr with exit status 2."""


def parse_args(argv: list[str] | None = None) -> Args:
    # tyro reports its own errors in a multi-line box; reduce them to our one-line convention.
    out, err = io.StringIO(), io.StringIO()
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            return tyro.cli(Args, args=argv)
    except SystemExit as exit_:
        if exit_.code in (0, None):
            sys.stdout.write(out.getvalue())
            raise
        # The box is: title, rule, message (possibly wrapped), rule, help; rules are ─ or - on a non-terminal.
        blocks: list[list[str]] = [[]]
        for line in (err.getvalue() or out.getvalue()).splitlines():
            line = line.strip(" │╭╮╰╯|")
            if line and set(line) <= set("─-"):
                blocks.append([])
            elif line:
                blocks[-1].append(line)
        message = " ".join(blocks[1]) if len(blocks) > 1 and blocks[1] else "invalid arguments"
        raise UsageError(message) from None


def validate(args: Args) -> tuple[dict[str, list] | None, dict | None]:
    """Checks everything before any file is written or environment started; returns (space, checkpoint), the
    checkpoint of --resume, --init-from or --evaluate."""
    checkpoint = None
    if args.resume is not None and args.init_from is not None:
        raise UsageError("--resume and --init-from exclude each other: --resume continues a run with its own settings")
    if args.evaluate is not None and (args.resume is not None or args.init_from is not None or args.track):
        raise UsageError("--evaluate plays a run's policy and writes nothing: it goes without --resume, --init-from "
                         "and --track")
    if args.evaluate is not None:
        checkpoint = load_checkpoint(args.evaluate, "--evaluate")
        args = evaluated_args(args, checkpoint)  # what is checked below is what the evaluation will use
    elif args.resume is not None:
        checkpoint = load_checkpoint(args.resume, "--resume")
        args = resumed_args(args, checkpoint)  # what is checked below is what the run will use
    elif args.init_from is not None:
        checkpoint = load_checkpoint(args.init_from, "--init-from")
        source = checkpoint["config"]
        # What the carried-over state was made with: the games being replayed, the rollout's shape.
        for name in ("env_id", "num_envs", "num_steps", "repeat_action_probability", "noop_max", "episodic_life"):
            if getattr(args, name) != source[name]:
                raise UsageError(f"--init-from {args.init_from}: its {name} is {source[name]!r}, this run's "
                                 f"--{name.replace('_', '-')} {getattr(args, name)!r}")
        if args.total_timesteps // (args.num_envs * args.num_steps) <= checkpoint["iteration"]:
            raise UsageError(f"--total-timesteps {args.total_timesteps}: the checkpoint of --init-from "
                             f"{args.init_from} is already at step {checkpoint['global_step']}")
    check_output_options(args)
    if game_rom(args.env_id) is None:
        raise UsageError(f"--env-id {args.env_id}: no such ALE game (a name like BattleZone, a ROM id like "
                         f"battle_zone, or a Gymnasium id like ALE/BattleZone-v5)")
    for name in ("num_envs", "num_steps", "total_timesteps", "update_epochs", "checkpoint_every"):
        if getattr(args, name) <= 0:
            raise UsageError(f"--{name.replace('_', '-')} must be positive, got {getattr(args, name)}")
    if args.torch_threads < 0:
        raise UsageError(f"--torch-threads must be >= 0 (0: one per core), got {args.torch_threads}")
    for name in ("eval_episodes", "noop_max", "env_threads"):
        if getattr(args, name) < 0:
            raise UsageError(f"--{name.replace('_', '-')} must be >= 0, got {getattr(args, name)}")
    if not (0 <= args.repeat_action_probability <= 1):
        raise UsageError(f"--repeat-action-probability must be in [0, 1], got {args.repeat_action_probability}")
    batch_size = args.num_envs * args.num_steps
    if args.total_timesteps < batch_size:
        raise UsageError(f"--total-timesteps {args.total_timesteps} is less than one rollout ({batch_size} steps)")
    for name in TUNABLE:
        check_setting(name, getattr(args, name), batch_size, f"--{name.replace('_', '-')}")
    if not (0 < args.gamma <= 1):
        raise UsageError(f"--gamma must be in (0, 1], got {args.gamma}")
    if not (0 <= args.gae_lambda <= 1):
        raise UsageError(f"--gae-lambda must be in [0, 1], got {args.gae_lambda}")
    if args.target_kl is not None and not args.target_kl > 0:
        raise UsageError(f"--target-kl must be positive, got {args.target_kl}")
    space = None
    if args.ultho:
        space = checked_search_space(args, batch_size)
        if not (math.isfinite(args.ultho_c) and args.ultho_c >= 0):
            raise UsageError(f"--ultho-c must be a finite number >= 0, got {args.ultho_c}")
        if args.ultho_window < 1:
            raise UsageError(f"--ultho-window must be >= 1, got {args.ultho_window}")
        if not (math.isfinite(args.ultho_exp3_eta) and args.ultho_exp3_eta > 0):
            raise UsageError(f"--ultho-exp3-eta must be a finite number > 0, got {args.ultho_exp3_eta}")
        if args.ultho_utility == "authors-return" and args.ultho_credit == "improvement":
            raise UsageError("--ultho-credit improvement does not go with --ultho-utility authors-return (a choice "
                             "would be measured against its own credit); use --ultho-credit level")
    if args.resume is None and args.evaluate is None:
        if os.sep in args.run_name or args.run_name in ("", ".", ".."):
            raise UsageError(f"--run-name {args.run_name!r} is not a plain directory name")
        run_dir = os.path.join(args.runs_dir, args.run_name)
        # --init-from may continue a run of this script in its own directory (its logs go on from the checkpoint).
        if os.path.exists(run_dir) and not (args.init_from is not None and is_run_of_this_script(run_dir)):
            raise UsageError(f"run directory {run_dir} already exists: pass --resume {run_dir} or another --run-name")
    return space, checkpoint


def checked_search_space(args: Args, batch_size: int) -> dict[str, list]:
    """The search space from --ultho-clusters, each value checked as a setting it would override."""
    try:
        space = parse_clusters(list(args.ultho_clusters), SEARCH_SPACE, allowed=TUNABLE)
    except ValueError as err:
        raise UsageError(f"--ultho-clusters: {err}") from None
    for name, values in space.items():
        for value in values:
            check_setting(name, value, batch_size, f"--ultho-clusters {name}")
    return space


def check_setting(name: str, value, batch_size: int, where: str) -> None:
    if name in ("minibatch_size", "update_epochs"):
        if not isinstance(value, int) or value <= 0:
            raise UsageError(f"{where}: {name} must be a positive integer, got {value!r}")
        if name == "minibatch_size" and batch_size % value:
            raise UsageError(f"{where}: minibatch size {value} does not divide the rollout of {batch_size} samples")
    elif name in ("learning_rate", "clip_coef", "max_grad_norm"):
        if not (math.isfinite(value) and value > 0):
            raise UsageError(f"{where}: {name} must be positive, got {value!r}")
    elif not (math.isfinite(value) and value >= 0):
        raise UsageError(f"{where}: {name} must be >= 0, got {value!r}")


def resumed_args(args: Args, checkpoint: dict) -> Args:
    """The arguments of the run that --resume continues: its checkpoint's, but for --resume, --quiet, --cuda and
    --torch-threads, which come from this command line."""
    return dataclasses.replace(Args(**checkpoint["config"]), resume=args.resume, quiet=args.quiet, cuda=args.cuda,
                               torch_threads=args.torch_threads)


def evaluated_args(args: Args, checkpoint: dict) -> Args:
    """The arguments of the run that --evaluate plays: its checkpoint's, but for --evaluate, --eval-episodes,
    --capture-video, --quiet, --cuda and --torch-threads, which come from this command line (nothing is tracked)."""
    return dataclasses.replace(Args(**checkpoint["config"]), evaluate=args.evaluate, eval_episodes=args.eval_episodes,
                               capture_video=args.capture_video, video_every=0, track=False, resume=None,
                               init_from=None, quiet=args.quiet, cuda=args.cuda, torch_threads=args.torch_threads)


def check_output_options(args: Args) -> None:
    """--track's W&B names and login, --capture-video's and --evaluate's numbers, before anything starts."""
    if args.evaluate is not None and args.eval_episodes < 1:
        raise UsageError(f"--evaluate plays --eval-episodes episodes: it must be >= 1, got {args.eval_episodes}")
    if args.video_every < 0:
        raise UsageError(f"--video-every must be >= 0 (0: the final evaluation only), got {args.video_every}")
    if args.video_every and not args.capture_video:
        raise UsageError(f"--video-every {args.video_every} records videos: add --capture-video")
    if args.capture_video and args.eval_episodes == 0:
        raise UsageError("--capture-video records evaluation episodes: --eval-episodes 0 runs none")
    if not args.track:
        if args.wandb_entity is not None or args.wandb_group is not None:
            raise UsageError("--wandb-entity and --wandb-group name where --track logs: add --track")
        return
    for flag, name in (("--wandb-project-name", args.wandb_project_name), ("--wandb-entity", args.wandb_entity),
                       ("--wandb-group", args.wandb_group)):
        if name is not None and not (0 < len(name) <= 128 and not set(name) & set("/\\#?%:")):
            raise UsageError(f"{flag} {name!r}: W&B names are 1 to 128 characters without / \\ # ? % :")
    if importlib.util.find_spec("wandb") is None:
        raise UsageError("--track needs the wandb package: pip install -r requirements.txt")
    if os.environ.get("WANDB_MODE", "").lower() not in ("offline", "disabled", "dryrun") and not wandb_logged_in():
        raise UsageError("--track: no W&B login on this machine: run `wandb login`, or set WANDB_MODE=offline to "
                         "log locally and `wandb sync` the run later")


def wandb_logged_in() -> bool:
    """Whether W&B finds an API key: WANDB_API_KEY, or the netrc entry `wandb login` writes for its host."""
    if os.environ.get("WANDB_API_KEY"):
        return True
    host = urllib.parse.urlparse(os.environ.get("WANDB_BASE_URL", "https://api.wandb.ai")).hostname
    try:
        return netrc.netrc(os.environ.get("NETRC")).authenticators(host) is not None
    except (OSError, netrc.NetrcParseError):
        return False


def load_checkpoint(run_dir: str, flag: str) -> dict:
    path = os.path.join(run_dir, "checkpoint.pt")
    if not os.path.isfile(path):
        raise UsageError(f"{flag} {run_dir}: no checkpoint.pt there")
    try:
        checkpoint = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as err:  # noqa: BLE001  (any unreadable file is bad input)
        raise UsageError(f"{flag} {run_dir}: checkpoint.pt is unreadable ({err.__class__.__name__})") from None
    if not isinstance(checkpoint, dict) or checkpoint.get("script") != SCRIPT:
        raise UsageError(f"{flag} {run_dir}: checkpoint.pt is not a {SCRIPT} checkpoint")
    if checkpoint.get("format") != CHECKPOINT_FORMAT:
        raise UsageError(f"{flag} {run_dir}: checkpoint format {checkpoint.get('format')!r} is not supported")
    return checkpoint


def is_run_of_this_script(run_dir: str) -> bool:
    try:
        checkpoint = torch.load(os.path.join(run_dir, "checkpoint.pt"), map_location="cpu", weights_only=False)
        return checkpoint["script"] == SCRIPT
    except Exception:  # noqa: BLE001  (missing or foreign: not a run to continue)
        return False


def restore(checkpoint: dict, args: Args, settings: Settings, agent: Agent, optimizer: torch.optim.Optimizer,
            bandit: Optional[ULTHO], minibatch_rng: np.random.Generator, device: torch.device) -> Settings:
    """Loads the network and the optimizer from the checkpoint of --resume or --init-from and returns the settings
    in force. --resume also takes the run's bandit and settings; --init-from keeps this command line's settings
    and starts its own bandit. The counters and the environments are main's to take."""
    agent.load_state_dict(checkpoint["agent"])
    optimizer.load_state_dict(checkpoint["optimizer"])
    resumed = args.resume is not None
    if resumed:
        if bandit is not None:
            bandit.load_state_dict(checkpoint["bandit"])
        settings = Settings(**checkpoint["settings"])
    # The optimizer's saved state carries the learning rate it had; apply the setting in force.
    for group in optimizer.param_groups:
        group["lr"] = settings.learning_rate
    # --init-from with another seed (a PBT trial copying another) draws from its own seed from here on.
    if resumed or checkpoint["config"]["seed"] == args.seed:
        restore_rng(checkpoint["rng"], device, minibatch_rng)
    return settings


def rng_state(device: torch.device, minibatch_rng: np.random.Generator) -> dict:
    return {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state(),
            "cuda": torch.cuda.get_rng_state_all() if device.type == "cuda" else None,
            "minibatch": minibatch_rng.bit_generator.state}


def restore_rng(state: dict, device: torch.device, minibatch_rng: np.random.Generator) -> None:
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    torch.set_rng_state(state["torch"])
    if device.type == "cuda" and state["cuda"] is not None:
        torch.cuda.set_rng_state_all(state["cuda"])  # actions are sampled on the device
    minibatch_rng.bit_generator.state = state["minibatch"]


def open_run_dir(run_dir: str, config: dict, checkpoint: Optional[dict], resumed: bool) -> SummaryWriter:
    """The run directory and its TensorBoard writer; a run that goes on from a checkpoint drops the events a
    killed process logged after it (purge_step)."""
    os.makedirs(run_dir, exist_ok=True)
    if not resumed and os.path.exists(os.path.join(run_dir, "summary.json")):
        os.remove(os.path.join(run_dir, "summary.json"))  # --init-from in place: the run is no longer finished
    writer = SummaryWriter(run_dir, purge_step=checkpoint["global_step"] + 1 if checkpoint is not None else None)
    if not resumed:
        writer.add_text("hyperparameters",
                        "|param|value|\n|-|-|\n" + "\n".join(f"|{k}|{v}|" for k, v in config.items()))
    return writer


def start_tracking(args: Args, run_dir: str, config: dict) -> Optional[object]:
    """With --track, the W&B run that mirrors this one: its config, the script's code, and the scalars of the
    TensorBoard writer opened after it. The W&B id is kept in the run directory (wandb_id), so a resumed run goes
    on in the same W&B run. None without --track."""
    if not args.track:
        return None
    import wandb  # only with --track: it takes a second to import

    os.makedirs(run_dir, exist_ok=True)
    id_path = os.path.join(run_dir, "wandb_id")
    if os.path.exists(id_path):
        with open(id_path, encoding="utf-8") as f:
            run_id = f.read().strip()
    else:
        run_id = secrets.token_hex(6)  # W&B ids are short lowercase letters and digits
        atomic_write_bytes(id_path, run_id.encode())
    return wandb.init(project=args.wandb_project_name, entity=args.wandb_entity, group=args.wandb_group,
                      name=args.run_name, id=run_id, resume="allow", config=config, sync_tensorboard=True,
                      save_code=True)


def stop_tracking(tracker: Optional[object], diverged: Optional[dict]) -> None:
    """Ends the W&B run once the TensorBoard writer is closed (its last scalars are synced first)."""
    if tracker is not None:
        tracker.finish(exit_code=0 if diverged is None else 1)


def video_path(run_dir: str, label: str, global_step: int) -> str:
    """runs/<run>/videos/<label>-step<global step>.mp4; the folder is made on first use."""
    os.makedirs(os.path.join(run_dir, "videos"), exist_ok=True)
    return os.path.join(run_dir, "videos", f"{label}-step{global_step}.mp4")


def write_video(path: str, frames: list[np.ndarray], fps: int) -> None:
    """RGB frames (height, width, 3) as an H.264 MP4 (PyAV's own FFmpeg, nothing to install), written atomically;
    odd sizes are padded by a pixel, which H.264's 4:2:0 colour needs."""
    height, width = frames[0].shape[:2]
    tmp = f"{path}.tmp"
    with av.open(tmp, "w", format="mp4") as container:
        stream = container.add_stream("libx264", rate=fps)
        stream.width, stream.height, stream.pix_fmt = width + width % 2, height + height % 2, "yuv420p"
        for frame in frames:
            frame = np.pad(frame, ((0, height % 2), (0, width % 2), (0, 0)), mode="edge")
            container.mux(stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24")))
        container.mux(stream.encode())
    os.replace(tmp, path)


def log_video(tracker: Optional[object], path: Optional[str]) -> None:
    """With --track, the MP4 goes to W&B too (videos/<label>)."""
    if tracker is not None and path is not None:
        import wandb

        label = os.path.basename(path).rsplit("-step", 1)[0]
        tracker.log({f"videos/{label}": wandb.Video(path, format="mp4")})


def report_evaluation(args: Args, checkpoint: dict, returns: list[float], path: Optional[str]) -> None:
    """--evaluate's result on stdout: mean and std, then every episode's return (exactly, as summary.json's eval)."""
    print(f"[{SCRIPT}] {args.evaluate} at step {checkpoint['global_step']}: mean return {np.mean(returns):.4g} ± "
          f"{np.std(returns):.4g} over {len(returns)} episodes" + (f", video {path}" if path else ""))
    print(f"[{SCRIPT}] returns: {json.dumps(returns)}", flush=True)


def save_checkpoint(path: str, checkpoint: dict) -> None:
    """Atomically: serialized in memory, then written to a sibling file, fsynced and renamed over the last one."""
    buffer = io.BytesIO()
    torch.save(checkpoint, buffer)
    atomic_write_bytes(path, buffer.getvalue())


def stop_non_finite(diverged: dict, settings: Settings, tuned: list[str], checkpoint_path: str) -> None:
    """Exit status 1 with where the run diverged and the settings in force, once summary.json has recorded the
    divergence (the tools count the run as finished); the last checkpoint stays as it was."""
    last = (f"the last good checkpoint is {checkpoint_path}" if os.path.exists(checkpoint_path)
            else "no checkpoint was written")
    print(f"{SCRIPT}: error: non-finite {diverged['what']} at iteration {diverged['iteration']} (step "
          f"{diverged['global_step']}) with {', '.join(f'{n}={format_value(getattr(settings, n))}' for n in tuned)}; "
          f"stopped, summary.json records the divergence, {last}", file=sys.stderr)
    sys.exit(1)


def log_iteration(writer: SummaryWriter, global_step: int, iteration_returns: list[float],
                  iteration_lengths: list[int], learning_rate: float, sps: int, losses: list[float],
                  b_returns: torch.Tensor, b_values: torch.Tensor, settings: Settings, tuned: list[str]) -> None:
    """The iteration's TensorBoard scalars, CleanRL's tags and the settings in force (docs/scripts.md)."""
    policy_loss, value_loss, entropy, old_approx_kl, approx_kl, clipfrac = losses
    var_y = b_returns.var()
    explained_var = (1 - (b_returns - b_values).var() / var_y).item() if var_y > 0 else float("nan")
    if iteration_returns:
        writer.add_scalar("charts/episodic_return", float(np.mean(iteration_returns)), global_step)
        writer.add_scalar("charts/episodic_length", float(np.mean(iteration_lengths)), global_step)
    writer.add_scalar("charts/learning_rate", learning_rate, global_step)
    writer.add_scalar("charts/SPS", sps, global_step)
    writer.add_scalar("losses/value_loss", value_loss, global_step)
    writer.add_scalar("losses/policy_loss", policy_loss, global_step)
    writer.add_scalar("losses/entropy", entropy, global_step)
    writer.add_scalar("losses/old_approx_kl", old_approx_kl, global_step)
    writer.add_scalar("losses/approx_kl", approx_kl, global_step)
    writer.add_scalar("losses/clipfrac", clipfrac, global_step)
    writer.add_scalar("losses/explained_variance", explained_var, global_step)
    for name in tuned:
        writer.add_scalar(f"hparams/{name}", getattr(settings, name), global_step)


def log_bandit(writer: SummaryWriter, bandit: ULTHO, credit: Optional[float], global_step: int) -> None:
    """The bandit's bounds, counts and choice (ultho/* tags) and the credit measured this iteration."""
    bandit_scalars = bandit.scalars()
    if credit is not None:
        bandit_scalars["ultho/credit"] = credit
    # One event holding them all: add_scalar costs about 0.14 ms a tag, over 10 ms an iteration on MiniGrid.
    writer.file_writer.add_summary(Summary(value=[
        Summary.Value(tag=tag, simple_value=float(x)) for tag, x in bandit_scalars.items()]), global_step)


def report_progress(progress: tqdm, args: Args, iteration: int, num_iterations: int, global_step: int, sps: int,
                    recent_returns: deque, choice_text: str) -> None:
    """The progress bar on a terminal; elsewhere a plain line at every 5% of the run (none with --quiet)."""
    recent = f"{np.mean(recent_returns):.3g}" if recent_returns else "-"
    progress.update(global_step - progress.n)
    progress.set_postfix_str(f"SPS {sps} | return {recent} | {choice_text}", refresh=False)
    report_every = max(1, num_iterations // 20)
    if progress.disable and not args.quiet and (iteration % report_every == 0 or iteration == num_iterations):
        print(f"[{SCRIPT}] step {global_step}/{args.total_timesteps} ({100 * iteration // num_iterations}%) | "
              f"SPS {sps} | return {recent} | {choice_text}", flush=True)


def human_normalized(env_id: str, score: float | None) -> float | None:
    """(score - random) / (human - random) for an ALE-5 game; None for another game or no score."""
    constants = HUMAN_NORMALIZATION.get(game_name(env_id))
    if constants is None or score is None:
        return None
    random_score, human_score = constants
    return (score - random_score) / (human_score - random_score)


def write_summary(run_dir: str, args: Args, config: dict, settings: Settings, tuned: list[str],
                  bandit: Optional[ULTHO], global_step: int, num_iterations: int, wall_time: float,
                  ultho_seconds: float, rollout_seconds: float, update_seconds: float, device: torch.device,
                  recent_returns: deque, recent_lengths: deque, eval_returns: list[float],
                  diverged: Optional[dict]) -> None:
    """summary.json (docs/scripts.md lists its keys, docs/atari.md the human-normalized score), written atomically
    when the run ends."""
    final_score = float(np.mean(recent_returns)) if recent_returns else None
    summary = {
        "script": SCRIPT,
        "env_id": args.env_id,
        "run_name": args.run_name,
        "run_dir": run_dir,
        "seed": args.seed,
        "settings": config,
        "ultho": args.ultho,
        "global_step": global_step,
        "iterations": num_iterations,
        "diverged": diverged,
        "wall_time_s": wall_time,
        "sps": global_step / wall_time if wall_time > 0 else None,
        "ultho_seconds": ultho_seconds,
        "ultho_share": ultho_seconds / wall_time if wall_time > 0 else None,
        "rollout_seconds": rollout_seconds,
        "update_seconds": update_seconds,
        "device": str(device),
        "precision": args.precision,
        "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
        "peak_cuda_mb": torch.cuda.max_memory_allocated(device) / 2**20 if device.type == "cuda" else None,
        "final_score": final_score,
        "final_score_episodes": len(recent_returns),
        "final_episode_length": float(np.mean(recent_lengths)) if recent_lengths else None,
        "eval": {
            "episodes": len(eval_returns),
            "mean_return": float(np.mean(eval_returns)) if eval_returns else None,
            "std_return": float(np.std(eval_returns)) if eval_returns else None,
            "returns": eval_returns,
        },
        "settings_in_force": {name: getattr(settings, name) for name in tuned},
        "human_normalized_score": human_normalized(args.env_id, final_score),
        "bandit": None if bandit is None else bandit.summary(args.ultho_utility),
    }
    atomic_save_json(os.path.join(run_dir, "summary.json"), summary)
    if not args.quiet and diverged is None:  # else the error line says where it stopped
        print(f"[{SCRIPT}] done: {global_step} steps in {wall_time:.0f}s, final score "
              f"{'-' if final_score is None else f'{final_score:.3f}'}, summary in {run_dir}/summary.json", flush=True)


def atomic_write_bytes(path: str, data: bytes) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def atomic_save_json(path: str, obj: dict) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=2, allow_nan=False) + "\n").encode())


if __name__ == "__main__":
    try:
        main(parse_args())
    except UsageError as err:
        print(f"{SCRIPT}: error: {err}", file=sys.stderr)
        sys.exit(2)

"""SAC with ULTHO hyperparameter optimization on the DeepMind Control Suite, in one file (CleanRL style).

The paper's off-policy experiment (Yuan et al., ICCV 2025, appendix "ULTHO's performance with off-policy RL
algorithms"): every T environment steps (``--ultho-interval``) the ULTHO bandit (``ultho_bandit.py``) picks one
hyperparameter cluster and one value in it, the SAC updates of the next T steps run with it
(``args.<name> = value``), and the choice is credited with the mean action value over the batches those updates
sampled: U = (1/W) sum_j (1/|B_j|) sum_{(s,a) in B_j} min(Q1(s, a), Q2(s, a)). ``--no-ultho`` is plain SAC.

SAC: CleanRL's ``sac_continuous_action.py`` (Haarnoja et al. 2018 with twin Q networks, target smoothing,
delayed policy updates and automatic entropy tuning), its defaults and networks, computed with less overhead:
one fused Adam step for both critics, the networks through ``F.linear`` without ``nn.Module`` dispatch, the
critics' parameters out of the policy loss's backward pass, the replay buffer one preallocated torch tensor
sampled with an index tensor, no host-device copy inside an update.

Environments: the state-based tasks of the DeepMind Control Suite (``dm_control.suite``, MuJoCo), named
``DOMAIN-TASK`` (``cheetah-run``, ``walker-walk``, ``cartpole-balance``, ...), observations flattened into one
vector, action repeat 1, 1000 steps an episode, no rendering; also any gymnasium environment with a Box action
space and a state-vector observation (``Pendulum-v1``, ...). docs/dmc.md has every choice.

    python sac_ultho_dmc.py --env-id cheetah-run --seed 1
    tensorboard --logdir runs
"""

import contextlib
import ctypes.util
import dataclasses
import importlib.util
import io
import json
import logging
import math
import netrc
import os
import random
import secrets
import sys
import time
import urllib.parse
import warnings
from collections import deque
from dataclasses import dataclass
from typing import Literal, Optional

import av
import gymnasium as gym
import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F
import tyro
from tensorboard.compat.proto.summary_pb2 import Summary
from torch.utils.tensorboard import SummaryWriter
from tqdm import tqdm

from ultho_bandit import ULTHO, format_value, parse_clusters

# Only --capture-video renders, off-screen. dm_control loads the OpenGL backend MUJOCO_GL names when it is imported
# and fails there if that backend's library is missing (MUJOCO_GL=egl is common on GPU clusters), so it gets one
# whose library is on this machine: the one asked for if it is EGL or OSMesa, else EGL, else OSMesa, else none
# (then --capture-video is refused). MUJOCO_GL=disabled turns rendering off.
if os.environ.get("MUJOCO_GL", "").lower() not in ("off", "disable", "disabled", "false", "0"):
    os.environ["MUJOCO_GL"] = next(
        (backend for backend in (os.environ.get("MUJOCO_GL", "").lower(), "egl", "osmesa")
         if backend in ("egl", "osmesa") and ctypes.util.find_library({"egl": "EGL", "osmesa": "OSMesa"}[backend])),
        "disabled")
from dm_control import suite

# dm_control's MuJoCo warns through absl about XML attributes its own task files use (cheetah's settotalmass);
# not ours to show (bad input must print one line, --quiet nothing).
logging.getLogger("absl").setLevel(logging.ERROR)

SCRIPT = "sac_ultho_dmc"
CHECKPOINT_FORMAT = 1
VIDEO_FPS = 30
"""frames per second of --capture-video's MP4s, one control step per frame (the suite's tasks step 10 to 25 ms,
so the videos play slower than real time)"""

SEARCH_SPACE = {
    "q_lr": [3e-4, 1e-3, 3e-3],
    "policy_lr": [1e-4, 3e-4, 1e-3],
    "batch_size": [128, 256, 512],
    "tau": [0.0025, 0.005, 0.01],
}
"""The default search space (not in the paper; docs/dmc.md says why): a bare name in --ultho-clusters takes
these values, CleanRL's default and a factor of about 3 (the batch size and tau: 2) either side."""

TUNABLE = ("q_lr", "policy_lr", "batch_size", "tau", "gamma", "policy_frequency", "target_network_frequency")
"""Settings a cluster may override; each is read afresh by every SAC update."""

LOG_STD_MIN, LOG_STD_MAX = -5.0, 2.0
"""The policy's log standard deviation is squashed into this range (CleanRL's, from SpinUp / D. Yarats)."""
HALF_LOG_2PI = 0.5 * math.log(2 * math.pi)


@dataclass
class Args:
    """SAC with ULTHO on the DeepMind Control Suite. SAC's settings are CleanRL's sac_continuous_action.py
    defaults; the budget (CleanRL: 1M steps), the search space and T are this project's (docs/dmc.md)."""

    exp_name: str = SCRIPT
    """the name of this experiment (part of the default run name)"""
    seed: int = 1
    """seed of the experiment (Python, NumPy, torch and every episode's environment seed)"""
    torch_deterministic: bool = True
    """if toggled, `torch.backends.cudnn.deterministic=True`"""
    cuda: bool = True
    """if toggled, use CUDA when it is available"""
    torch_threads: int = 1
    """CPU threads for torch (one by default; docs/dmc.md says how to measure whether two pay on your machine)"""
    run_name: Optional[str] = None
    """name of the run directory under --runs-dir (default: {env_id}__{exp_name}__{seed}__{unix time})"""
    runs_dir: str = "runs"
    """directory that holds the run directories"""

    # Environment and SAC (CleanRL's defaults)
    env_id: str = "cheetah-run"
    """a DeepMind Control Suite task, DOMAIN-TASK (cheetah-run, walker-walk, cartpole-balance, ...), or a
    gymnasium environment with a Box action space and a state-vector observation (Pendulum-v1, ...)"""
    total_timesteps: int = 500_000
    """total environment steps of the run (rounded down to whole iterations of --ultho-interval steps)"""
    num_envs: int = 1
    """number of environments, stepped in turn; each vector step adds num_envs transitions and does one update"""
    buffer_size: int = 1_000_000
    """replay buffer capacity in transitions (the oldest are overwritten)"""
    gamma: float = 0.99
    """discount factor"""
    tau: float = 0.005
    """target smoothing coefficient: target <- tau * online + (1 - tau) * target"""
    batch_size: int = 256
    """transitions per update, sampled uniformly with replacement from the replay buffer"""
    learning_starts: int = 5000
    """environment steps of uniformly random actions before the first update"""
    policy_lr: float = 3e-4
    """Adam learning rate of the policy"""
    q_lr: float = 1e-3
    """Adam learning rate of the two Q networks and of the entropy coefficient (CleanRL ties the two)"""
    policy_frequency: int = 2
    """the policy is updated every policy_frequency critic updates, policy_frequency times (TD3's delay,
    compensated)"""
    target_network_frequency: int = 1
    """critic updates between target network updates"""
    alpha: float = 0.2
    """entropy coefficient when it is not tuned (--no-autotune)"""
    autotune: bool = True
    """tune the entropy coefficient towards the target entropy -|A| (automatic entropy tuning)"""

    # ULTHO
    ultho: bool = True
    """tune hyperparameters with ULTHO; --no-ultho runs plain SAC with fixed settings"""
    ultho_interval: int = 1000
    """T: environment steps between ULTHO's choices, one iteration (also the logging and checkpoint unit with
    --no-ultho); a multiple of --num-envs"""
    ultho_c: float = 5.0
    """exploration coefficient c of Eqs. 4-5 (paper grid: 1, 5)"""
    ultho_window: int = 10
    """window W of the utility's moving average, Eq. 6 (paper grid: 10, 50, 100)"""
    ultho_clusters: tuple[str, ...] = tuple(SEARCH_SPACE)
    """search space: NAME takes the default values, NAME=V1,V2,... sets them; one cluster = a Relay run"""
    ultho_strategy: Literal["ucb", "ts", "exp3", "round-robin"] = "ucb"
    """how the bandit chooses at both levels: ucb (Eqs. 4-5, the paper's), ts (Gaussian Thompson sampling),
    exp3 (discounted Exp3) or round-robin (the values in turn, the control without a bandit);
    docs/strategies.md says when to use which"""
    ultho_credit: Literal["level", "improvement"] = "level"
    """what a choice is credited with: the utility as measured (level, the paper's) or its change from the
    previous interval's (improvement)"""
    ultho_scale: Literal["none", "running"] = "none"
    """none (the paper's) or running: utilities in units of the credits' running standard deviation, so c
    means the same whatever the task's value scale"""
    ultho_exp3_eta: float = 0.5
    """Exp3's learning rate (with --ultho-strategy exp3)"""

    # Evaluation, checkpoints, output
    eval_episodes: int = 10
    """episodes of the final policy's mean action on fresh environments for summary.json (0: skip)"""
    checkpoint_every: int = 10
    """iterations between checkpoints (one is also written at the end); each holds the replay buffer"""
    resume: Optional[str] = None
    """run directory to continue to its --total-timesteps; its checkpoint's settings are used"""
    init_from: Optional[str] = None
    """run directory whose checkpoint this run starts from: networks, optimizers, entropy coefficient, replay
    buffer, environments and counters are taken from it, every setting from this command line
    (docs/hpo_baselines.md)"""
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

    @property
    def num_steps(self) -> int:
        """Steps per environment per iteration: an iteration is num_envs x num_steps environment steps, as in
        the PPO scripts (hpo_baselines.py reads it)."""
        return self.ultho_interval // self.num_envs

    def __post_init__(self) -> None:
        if self.run_name is None:  # resolved once, when the command line is parsed: every later use agrees
            self.run_name = f"{self.env_id}__{self.exp_name}__{self.seed}__{int(time.time())}"


@dataclass
class Settings:
    """The settings in force: the TUNABLE ones, which ULTHO changes one at a time and every SAC update reads
    afresh. They start as the command line's (``args`` itself is never changed), are saved in the checkpoint
    and are summary.json's ``settings_in_force``."""

    q_lr: float
    policy_lr: float
    batch_size: int
    tau: float
    gamma: float
    policy_frequency: int
    target_network_frequency: int

    @classmethod
    def from_args(cls, args: Args) -> "Settings":
        return cls(**{name: getattr(args, name) for name in TUNABLE})


# ---------------------------------------------------------------------- environments
class DMCEnv(gym.Env):
    """A DeepMind Control Suite task as a gymnasium environment: the observation dict flattened into one
    float32 vector in the task's own key order, the action box of its action spec, 1000 steps an episode
    (truncated: the suite's time limit; terminated only where a task's discount is 0). ``reset(seed=s)``
    reseeds the task's random state, so an episode depends on its seed and its actions alone (the suite's
    reset restores MuJoCo's whole state, mj_resetData, before the task initializes the episode)."""

    metadata = {"render_modes": ["rgb_array"]}

    def __init__(self, env_id: str):
        domain, task = env_id.split("-", 1)
        self._env = suite.load(domain, task, task_kwargs={"random": 0})
        shapes = [tuple(spec.shape) for spec in self._env.observation_spec().values()]
        self._slices, start = [], 0
        for shape in shapes:
            size = int(np.prod(shape))
            self._slices.append(slice(start, start + size))
            start += size
        self.observation_space = gym.spaces.Box(-np.inf, np.inf, (start,), np.float32)
        spec = self._env.action_spec()
        self.action_space = gym.spaces.Box(spec.minimum.astype(np.float32), spec.maximum.astype(np.float32),
                                           dtype=np.float32)

    def _flat(self, observation) -> np.ndarray:
        out = np.empty(self.observation_space.shape, dtype=np.float32)
        for part, value in zip(self._slices, observation.values()):
            out[part] = np.ravel(value)
        return out

    def reset(self, *, seed: Optional[int] = None, options: Optional[dict] = None):
        if seed is not None:
            self._env.task.random.seed(seed)
        return self._flat(self._env.reset().observation), {}

    def step(self, action):
        time_step = self._env.step(action)
        terminated = time_step.last() and time_step.discount == 0.0
        return (self._flat(time_step.observation), float(time_step.reward), terminated,
                time_step.last() and not terminated, {})

    def render(self) -> np.ndarray:
        """The task's first camera, 320x240 RGB (off-screen, through the backend MUJOCO_GL names)."""
        return self._env.physics.render(height=240, width=320, camera_id=0)


def make_env(env_id: str, render: bool = False) -> gym.Env:
    """A suite task by its DOMAIN-TASK name, else a registered gymnasium environment (Pendulum-v1, the
    gymnasium MuJoCo tasks, ...) without gymnasium's environment checker (its warnings would break --quiet);
    render: one whose render() returns an RGB frame (a suite task's always does)."""
    domain, _, task = env_id.partition("-")
    if (domain, task) in suite.ALL_TASKS:
        return DMCEnv(env_id)
    return gym.make(env_id, disable_env_checker=True, render_mode="rgb_array" if render else None)


class ReplayableEnvs:
    """num_envs environments stepped in turn, with gymnasium's SAME_STEP autoreset (a finished episode's next
    observation is the new episode's first), whose exact state a checkpoint can hold although MuJoCo's cannot
    be restored exactly from its state vector alone (the solver's warm start is not in it): every episode
    begins with reset(seed=its own seed) and its actions are kept, so fresh environments reach the same state
    by replaying them (at most one episode: 1000 steps of a suite task, a tenth of a second). Exact where an
    episode depends on its seed and actions alone: the suite's tasks, gymnasium's classic-control and MuJoCo
    tasks."""

    def __init__(self, env_id: str, num_envs: int, seed_key: tuple[int, ...]):
        self.envs = [make_env(env_id) for _ in range(num_envs)]
        self.seed_key = seed_key
        self.episodes = [0] * num_envs  # episodes begun per environment
        self.actions: list[list[np.ndarray]] = [[] for _ in range(num_envs)]
        self.single_observation_space = self.envs[0].observation_space
        self.single_action_space = self.envs[0].action_space

    def _begin_episode(self, k: int) -> np.ndarray:
        seed = episode_seed(*self.seed_key, k, self.episodes[k])
        self.episodes[k] += 1
        self.actions[k] = []
        return self.envs[k].reset(seed=seed)[0]

    def reset(self) -> np.ndarray:
        return np.stack([self._begin_episode(k) for k in range(len(self.envs))])

    def step(self, actions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(observations for the next action, the true next observations, rewards, terminated, truncated):
        the two observations differ where an episode ended (the first is then the new episode's)."""
        n = len(self.envs)
        observations = np.empty((n, *self.single_observation_space.shape), dtype=np.float32)
        final = np.empty_like(observations)
        rewards, terminated, truncated = np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        for k, env in enumerate(self.envs):
            self.actions[k].append(actions[k])
            final[k], rewards[k], terminated[k], truncated[k], _ = env.step(actions[k])
            observations[k] = self._begin_episode(k) if terminated[k] or truncated[k] else final[k]
        return observations, final, rewards, terminated, truncated

    def state_dict(self) -> dict:
        return {"seed_key": self.seed_key, "episodes": list(self.episodes),
                "actions": [np.array(a, dtype=np.float32).reshape(len(a), *self.single_action_space.shape)
                            for a in self.actions]}

    @classmethod
    def from_state_dict(cls, env_id: str, state: dict) -> "ReplayableEnvs":
        envs = cls(env_id, len(state["episodes"]), tuple(state["seed_key"]))
        for k, (episodes, actions) in enumerate(zip(state["episodes"], state["actions"])):
            envs.episodes[k] = episodes - 1
            envs._begin_episode(k)
            for action in actions:
                envs.envs[k].step(action)
            envs.actions[k] = list(actions)
        return envs


def episode_seed(*key: int) -> int:
    """An environment seed drawn from the key (run seed, purpose, environment, episode): distinct streams for
    training and evaluation, and no episode shared between runs with neighbouring seeds."""
    return int(np.random.SeedSequence(list(key)).generate_state(1)[0])


# ---------------------------------------------------------------------- networks
class Actor(nn.Module):
    """CleanRL's actor: two 256-unit ReLU layers, then the mean and the log standard deviation of a Gaussian
    (one Linear of 2|A| outputs: the same initialization as CleanRL's two heads), the log std squashed into
    [LOG_STD_MIN, LOG_STD_MAX] by tanh, the sample squashed onto the action box by tanh."""

    def __init__(self, obs_size: int, action_size: int, low: np.ndarray, high: np.ndarray):
        super().__init__()
        self.fc1 = nn.Linear(obs_size, 256)
        self.fc2 = nn.Linear(256, 256)
        self.head = nn.Linear(256, 2 * action_size)
        self.register_buffer("action_scale", torch.tensor((high - low) / 2.0, dtype=torch.float32))
        self.register_buffer("action_bias", torch.tensor((high + low) / 2.0, dtype=torch.float32))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(mean, log std) of the Gaussian before the tanh, each (N, A). F.linear on the parameters: nn.Module's
        per-call dispatch would cost more than the one-row forward of every environment step."""
        x = F.relu(F.linear(obs, self.fc1.weight, self.fc1.bias), inplace=True)
        x = F.relu(F.linear(x, self.fc2.weight, self.fc2.bias), inplace=True)
        mean, log_std = F.linear(x, self.head.weight, self.head.bias).chunk(2, dim=-1)
        # LOG_STD_MIN + (LOG_STD_MAX - LOG_STD_MIN) * (tanh + 1) / 2, in two ops
        return mean, torch.tanh(log_std).mul(0.5 * (LOG_STD_MAX - LOG_STD_MIN)).add(0.5 * (LOG_STD_MAX + LOG_STD_MIN))

    def sample(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(action, log pi(action | obs)) with the reparameterization trick, x = mean + std * eps. log N(x; mean,
        std) is written out as -eps^2/2 - log std - log(2 pi)/2 (what torch.distributions.Normal computes, with
        the same gradients: eps is a constant), less the tanh's log-Jacobian log(scale * (1 - tanh(x)^2) + 1e-6);
        fused where torch has the op (addcmul), since every op costs autograd a node on these small tensors."""
        mean, log_std = self(obs)
        eps = torch.randn_like(mean)
        y = torch.tanh(torch.addcmul(mean, log_std.exp(), eps))
        log_jacobian = torch.log(torch.addcmul(self.action_scale + 1e-6, self.action_scale, y.square(), value=-1))
        constant = (-0.5 * eps.square() - HALF_LOG_2PI).sum(-1)
        return torch.addcmul(self.action_bias, y, self.action_scale), constant - (log_std + log_jacobian).sum(-1)

    def mean_action(self, obs: torch.Tensor) -> torch.Tensor:
        """The deterministic policy (the evaluation's): tanh of the mean, onto the action box."""
        return torch.tanh(self(obs)[0]) * self.action_scale + self.action_bias


class SoftQNetwork(nn.Module):
    """CleanRL's soft Q network: Linear(|S|+|A|, 256)-ReLU-Linear(256, 256)-ReLU-Linear(256, 1), nn.Linear's
    default initialization."""

    def __init__(self, input_size: int):
        super().__init__()
        self.fc1 = nn.Linear(input_size, 256)
        self.fc2 = nn.Linear(256, 256)
        self.fc3 = nn.Linear(256, 1)

    def forward(self, obs_action: torch.Tensor, detached: bool = False) -> torch.Tensor:
        """Q of (N, |S|+|A|) state-action rows, as (N,). ``detached``: the parameters take no gradient (the
        policy's loss differentiates through the critics with respect to the action only)."""
        params = [self.fc1.weight, self.fc1.bias, self.fc2.weight, self.fc2.bias, self.fc3.weight, self.fc3.bias]
        if detached:
            params = [p.detach() for p in params]
        w1, b1, w2, b2, w3, b3 = params
        x = F.relu(F.linear(obs_action, w1, b1), inplace=True)
        x = F.relu(F.linear(x, w2, b2), inplace=True)
        return F.linear(x, w3, b3).squeeze(-1)


class TwinQ(nn.Module):
    """SAC's two independent soft Q networks; their values side by side as (2, N). One Adam over both networks'
    parameters updates them in one (fused) step, as CleanRL's q_optimizer. (Both networks as one batched
    matmul, torch.baddbmm on stacked weights, measured no faster on the CPU than these twelve mm calls.)"""

    def __init__(self, input_size: int):
        super().__init__()
        self.q1 = SoftQNetwork(input_size)
        self.q2 = SoftQNetwork(input_size)

    def forward(self, obs_action: torch.Tensor, detached: bool = False) -> tuple[torch.Tensor, torch.Tensor]:
        return self.q1(obs_action, detached), self.q2(obs_action, detached)


@dataclass
class SAC:
    """The learner: networks, entropy coefficient and optimizers, as CleanRL's script holds them in variables."""

    actor: Actor
    critic: TwinQ
    critic_target: TwinQ
    log_alpha: torch.Tensor
    alpha: torch.Tensor
    """exp(log_alpha), detached (or the fixed --alpha): the coefficient every loss uses"""
    target_entropy: float
    actor_optimizer: torch.optim.Optimizer
    q_optimizer: torch.optim.Optimizer
    alpha_optimizer: Optional[torch.optim.Optimizer]

    @classmethod
    def create(cls, obs_size: int, action_size: int, low: np.ndarray, high: np.ndarray, args: Args,
               device: torch.device) -> "SAC":
        actor = Actor(obs_size, action_size, low, high).to(device)
        critic = TwinQ(obs_size + action_size).to(device)
        critic_target = TwinQ(obs_size + action_size).to(device)
        critic_target.load_state_dict(critic.state_dict())
        critic_target.requires_grad_(False)
        # Fused Adam (one kernel over all tensors); CleanRL's Adam otherwise (default betas and eps).
        log_alpha = torch.zeros(1, requires_grad=True, device=device)
        return cls(actor, critic, critic_target, log_alpha,
                   log_alpha.detach().exp() if args.autotune else torch.tensor([args.alpha], device=device),
                   -float(action_size),
                   torch.optim.Adam(actor.parameters(), lr=args.policy_lr, fused=True),
                   torch.optim.Adam(critic.parameters(), lr=args.q_lr, fused=True),
                   torch.optim.Adam([log_alpha], lr=args.q_lr, fused=True) if args.autotune else None)

    def apply_learning_rates(self, settings: Settings) -> None:
        """Puts the learning rates in force on the optimizers (q_lr also drives the entropy coefficient's, as in
        CleanRL)."""
        for optimizer, lr in ((self.actor_optimizer, settings.policy_lr), (self.q_optimizer, settings.q_lr),
                              (self.alpha_optimizer, settings.q_lr)):
            if optimizer is not None:
                for group in optimizer.param_groups:
                    group["lr"] = lr

    def state_dict(self) -> dict:
        return {"actor": self.actor.state_dict(), "critic": self.critic.state_dict(),
                "critic_target": self.critic_target.state_dict(), "log_alpha": self.log_alpha.detach().clone(),
                "alpha": self.alpha.clone(), "actor_optimizer": self.actor_optimizer.state_dict(),
                "q_optimizer": self.q_optimizer.state_dict(),
                "alpha_optimizer": None if self.alpha_optimizer is None else self.alpha_optimizer.state_dict()}

    def load_state_dict(self, state: dict, args: Args) -> None:
        """The learner of a checkpoint; an --init-from run that changes --autotune or --alpha keeps the source's
        log_alpha and starts its entropy coefficient from it (autotune) or from --alpha."""
        self.actor.load_state_dict(state["actor"])
        self.critic.load_state_dict(state["critic"])
        self.critic_target.load_state_dict(state["critic_target"])
        with torch.no_grad():
            self.log_alpha.copy_(state["log_alpha"])
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.q_optimizer.load_state_dict(state["q_optimizer"])
        if self.alpha_optimizer is not None and state["alpha_optimizer"] is not None:
            self.alpha_optimizer.load_state_dict(state["alpha_optimizer"])
        self.alpha.copy_(self.log_alpha.detach().exp() if args.autotune else torch.tensor([args.alpha]))


def sac_update(sac: SAC, batch: torch.Tensor, update: int, settings: Settings, obs_size: int,
               action_size: int) -> tuple[torch.Tensor, Optional[torch.Tensor]]:
    """SAC update number ``update`` (1, 2, ...) on a batch of replay rows [obs, action, reward, terminated,
    next obs], CleanRL's: a critic step, every policy_frequency updates policy_frequency policy steps (each
    followed by an entropy-coefficient step), every target_network_frequency updates the target smoothing.

    Returns the critics' statistics [qf1_loss, qf2_loss, qf1_values, qf2_values, min_qf_values] — the last is
    ULTHO's per-batch utility, (1/|B|) sum over the batch of min(Q1(s, a), Q2(s, a)) as the critic loss saw it,
    before its gradient step — and, after policy steps, [actor_loss, alpha_loss] of the last one; all
    detached and on the device (nothing here waits for it)."""
    obs_action = batch[:, :obs_size + action_size]  # the stored state-action rows, already side by side
    obs = batch[:, :obs_size]
    reward, terminated = batch[:, obs_size + action_size], batch[:, obs_size + action_size + 1]
    next_obs = batch[:, obs_size + action_size + 2:]

    with torch.no_grad():
        next_action, next_log_prob = sac.actor.sample(next_obs)
        next_q = torch.minimum(*sac.critic_target(torch.cat([next_obs, next_action], dim=1)))
        target = reward + (1 - terminated) * settings.gamma * (next_q - sac.alpha * next_log_prob)
    q1, q2 = sac.critic(obs_action)
    qf1_loss, qf2_loss = F.mse_loss(q1, target), F.mse_loss(q2, target)
    sac.q_optimizer.zero_grad(set_to_none=True)
    (qf1_loss + qf2_loss).backward()
    sac.q_optimizer.step()
    critic_stats = torch.stack([qf1_loss, qf2_loss, q1.mean(), q2.mean(), torch.minimum(q1, q2).mean()]).detach()

    actor_stats = None
    if update % settings.policy_frequency == 0:  # TD3's delayed update, compensated by policy_frequency steps
        for _ in range(settings.policy_frequency):
            action, log_prob = sac.actor.sample(obs)
            q_pi = torch.minimum(*sac.critic(torch.cat([obs, action], dim=1), detached=True))
            actor_loss = (sac.alpha * log_prob - q_pi).mean()
            sac.actor_optimizer.zero_grad(set_to_none=True)
            actor_loss.backward()
            sac.actor_optimizer.step()
            alpha_loss = torch.zeros((), device=batch.device)
            if sac.alpha_optimizer is not None:
                # The entropy coefficient's step on the log-probabilities the policy's loss used (SAC's and SB3's;
                # CleanRL samples the policy once more after its step, a forward pass more per policy step).
                alpha_loss = (-sac.log_alpha.exp() * (log_prob.detach() + sac.target_entropy)).mean()
                sac.alpha_optimizer.zero_grad(set_to_none=True)
                alpha_loss.backward()
                sac.alpha_optimizer.step()
                sac.alpha.copy_(sac.log_alpha.detach().exp())
        actor_stats = torch.stack([actor_loss, alpha_loss]).detach()

    if update % settings.target_network_frequency == 0:
        with torch.no_grad():  # target <- target + tau * (param - target), all twelve tensors in one call
            torch._foreach_lerp_(list(sac.critic_target.parameters()), list(sac.critic.parameters()), settings.tau)
    return critic_stats, actor_stats


class IntervalStats:
    """What one interval's updates measured: sums of sac_update's statistics, kept on the device and read
    once when the interval ends. ``means()["min_qf_values"]`` is ULTHO's utility of the interval, the mean
    over its batches of each batch's mean min-Q: (1/W) sum_j (1/|B_j|) sum_{(s,a) in B_j} min(Q1, Q2)(s, a)."""

    CRITIC = ("qf1_loss", "qf2_loss", "qf1_values", "qf2_values", "min_qf_values")
    ACTOR = ("actor_loss", "alpha_loss")

    def __init__(self, device: torch.device):
        self.critic_sum = torch.zeros(len(self.CRITIC), device=device)
        self.actor_sum = torch.zeros(len(self.ACTOR), device=device)
        self.updates, self.actor_updates, self.sampled_rows = 0, 0, 0

    def add(self, batch_size: int, critic_stats: torch.Tensor, actor_stats: Optional[torch.Tensor]) -> None:
        self.critic_sum += critic_stats
        self.updates += 1
        self.sampled_rows += batch_size
        if actor_stats is not None:
            self.actor_sum += actor_stats
            self.actor_updates += 1

    def means(self) -> dict[str, float]:
        """Each statistic's mean over the updates that produced it (empty before the first update), and
        ``batch_size``, the mean number of rows the updates sampled."""
        out = {}
        if self.updates:
            out.update(zip(self.CRITIC, (self.critic_sum / self.updates).tolist()))
            out["batch_size"] = self.sampled_rows / self.updates
        if self.actor_updates:
            out.update(zip(self.ACTOR, (self.actor_sum / self.actor_updates).tolist()))
        return out


# ---------------------------------------------------------------------- the training loop
def main(args: Args) -> None:
    space, checkpoint = validate(args)  # nothing is written or started before this returns
    if args.evaluate is not None:  # a finished run's policy, not a training run
        evaluate_run(evaluated_args(args, checkpoint), checkpoint)
        return
    resumed = args.resume is not None
    if resumed:  # the run goes on with its own arguments
        args = resumed_args(args, checkpoint)

    T = args.ultho_interval
    num_iterations = args.total_timesteps // T
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
    action_rng = np.random.default_rng(args.seed)  # the random actions before learning starts

    bandit = ULTHO(space, c=args.ultho_c, window=args.ultho_window, strategy=args.ultho_strategy,
                   credit=args.ultho_credit, scale=args.ultho_scale, seed=args.seed,
                   exp3_eta=args.ultho_exp3_eta) if args.ultho else None
    tuned = list(space) if space is not None else list(SEARCH_SPACE)
    settings = Settings.from_args(args)  # the settings in force, which ULTHO changes

    envs = (ReplayableEnvs(args.env_id, args.num_envs, (args.seed, 0)) if checkpoint is None
            else ReplayableEnvs.from_state_dict(args.env_id, checkpoint["envs"]))
    obs_size, action_size = envs.single_observation_space.shape[0], envs.single_action_space.shape[0]
    action_low, action_high = envs.single_action_space.low, envs.single_action_space.high
    sac = SAC.create(obs_size, action_size, action_low, action_high, args, device)

    # The replay buffer: one preallocated tensor on the device, a row per transition:
    # [obs, action, reward, terminated, next obs]. One gather by an index tensor samples a batch. Empty, not
    # zeroed: rows past `filled` are never read, and the pages of unwritten rows cost no memory until written.
    row_size = 2 * obs_size + action_size + 2
    storage = torch.empty((args.buffer_size, row_size), dtype=torch.float32, device=device)
    position, filled = 0, 0  # the next row to write; rows holding transitions

    start_iteration, global_step, elapsed_before = 1, 0, 0.0
    num_updates = 0
    ultho_seconds = 0.0  # wall time spent on ULTHO's own work, reported as its share of the run
    last_utility: Optional[float] = None  # the previous interval's utility (--ultho-credit improvement's baseline)
    episode_return = np.zeros(args.num_envs)
    episode_length = np.zeros(args.num_envs, dtype=np.int64)
    recent_returns: deque[float] = deque(maxlen=100)
    recent_lengths: deque[int] = deque(maxlen=100)
    if checkpoint is None:
        next_obs = envs.reset()
    else:
        sac.load_state_dict(checkpoint["sac"], args)
        if resumed:  # --init-from keeps this command line's settings and starts its own bandit
            if bandit is not None:
                bandit.load_state_dict(checkpoint["bandit"])
            settings = Settings(**checkpoint["settings"])
            last_utility = checkpoint["last_utility"]
        position, filled = checkpoint["replay"]["position"], checkpoint["replay"]["filled"]
        storage[:filled] = checkpoint["replay"]["rows"].to(device)
        next_obs = checkpoint["next_obs"]
        start_iteration = checkpoint["iteration"] + 1
        global_step, num_updates = checkpoint["global_step"], checkpoint["num_updates"]
        elapsed_before, ultho_seconds = checkpoint["elapsed"], checkpoint["ultho_seconds"]
        episode_return, episode_length = checkpoint["episode_return"], checkpoint["episode_length"]
        recent_returns.extend(checkpoint["recent_returns"])
        recent_lengths.extend(checkpoint["recent_lengths"])
        # --init-from with another seed (a PBT trial copying another) draws from its own seed from here on.
        if resumed or checkpoint["config"]["seed"] == args.seed:
            restore_rng(checkpoint["rng"], device, action_rng)
    sac.apply_learning_rates(settings)  # the optimizers' saved state carries the rates they had
    tracker = start_tracking(args, run_dir, config)  # before the writer: W&B syncs the scalars it writes
    writer = open_run_dir(run_dir, config, checkpoint, resumed)

    progress = tqdm(total=args.total_timesteps, initial=global_step, unit="step", dynamic_ncols=True,
                    disable=args.quiet or not sys.stderr.isatty())
    start_time, start_step = time.time(), global_step
    diverged = None  # where the run stopped with non-finite numbers, if it did
    for iteration in range(start_iteration, num_iterations + 1):
        # 1. ULTHO chooses a cluster and a value for this interval's updates (if it has any).
        selected, credit = None, None
        if bandit is not None and global_step + T > args.learning_starts:
            tick = time.perf_counter()
            if last_utility is None:  # the first choice: the critics' value on one batch (0 before any data)
                last_utility = 0.0
                if filled:
                    with torch.no_grad():
                        rows = storage[torch.randint(filled, (settings.batch_size,), device=device)]
                        last_utility = torch.minimum(*sac.critic(rows[:, :obs_size + action_size])).mean().item()
            cluster, choice = bandit.select(before=last_utility)
            setattr(settings, cluster, choice)
            sac.apply_learning_rates(settings)
            selected = bandit.scalars()  # the bounds this choice maximised, logged below
            ultho_seconds += time.perf_counter() - tick

        # 2. T environment steps, a SAC update after each once learning has started.
        iteration_returns: list[float] = []
        iteration_lengths: list[int] = []
        interval = IntervalStats(device)
        for _ in range(T // args.num_envs):
            global_step += args.num_envs
            if global_step <= args.learning_starts:
                actions = action_rng.uniform(action_low, action_high, (args.num_envs, action_size)).astype(np.float32)
            else:
                with torch.no_grad():
                    actions = sac.actor.sample(torch.from_numpy(next_obs).to(device))[0].cpu().numpy()
                if not np.isfinite(actions).all():  # diverged networks: stop before the physics is given NaN
                    diverged = {"what": "action", "iteration": iteration, "global_step": global_step}
                    break
            obs = next_obs
            next_obs, final_obs, rewards, terminated, truncated = envs.step(actions)
            rows = np.concatenate([obs, actions, rewards[:, None], terminated[:, None], final_obs], axis=1)
            for row in torch.from_numpy(rows.astype(np.float32)).to(device):
                storage[position] = row
                position = (position + 1) % args.buffer_size
            filled = min(filled + args.num_envs, args.buffer_size)
            episode_return += rewards
            episode_length += 1
            done = terminated | truncated
            if done.any():
                finished = np.flatnonzero(done)
                iteration_returns += episode_return[finished].tolist()
                iteration_lengths += episode_length[finished].tolist()
                episode_return[finished] = 0.0
                episode_length[finished] = 0

            if global_step > args.learning_starts:
                num_updates += 1
                batch = storage[torch.randint(filled, (settings.batch_size,), device=device)]
                interval.add(batch.shape[0], *sac_update(sac, batch, num_updates, settings, obs_size, action_size))
        recent_returns.extend(iteration_returns)  # the episodes that ended before a divergence count too
        recent_lengths.extend(iteration_lengths)
        if diverged is not None:
            break

        # 3. The interval's statistics, and ULTHO's credit: the mean over its batches of each batch's mean min-Q.
        stats = interval.means()
        if not all(map(math.isfinite, stats.values())):
            # The weights are no longer finite: the run ends here, summary.json records where, and the
            # last good checkpoint stays as it was.
            diverged = {"what": "loss", "iteration": iteration, "global_step": global_step}
            break
        if selected is not None:
            tick = time.perf_counter()
            credit = stats["min_qf_values"]
            bandit.update(credit)
            last_utility = credit
            ultho_seconds += time.perf_counter() - tick

        # 4. Log.
        elapsed = time.time() - start_time
        sps = int((global_step - start_step) / elapsed) if elapsed > 0 else 0
        if iteration_returns:
            writer.add_scalar("charts/episodic_return", float(np.mean(iteration_returns)), global_step)
            writer.add_scalar("charts/episodic_length", float(np.mean(iteration_lengths)), global_step)
        writer.add_scalar("charts/SPS", sps, global_step)
        if interval.updates:
            # What the updates ran with: the optimizers' learning rates, the mean size of the batches sampled.
            writer.add_scalar("charts/q_lr", sac.q_optimizer.param_groups[0]["lr"], global_step)
            writer.add_scalar("charts/policy_lr", sac.actor_optimizer.param_groups[0]["lr"], global_step)
            writer.add_scalar("charts/batch_size", stats.pop("batch_size"), global_step)
            if not args.autotune:
                stats.pop("alpha_loss", None)
            for tag, value in stats.items():
                writer.add_scalar(f"losses/{tag}", value, global_step)
            writer.add_scalar("losses/qf_loss", (stats["qf1_loss"] + stats["qf2_loss"]) / 2, global_step)
            writer.add_scalar("losses/alpha", sac.alpha.item(), global_step)
        for name in tuned:
            writer.add_scalar(f"hparams/{name}", getattr(settings, name), global_step)
        if selected is not None:
            tick = time.perf_counter()
            selected["ultho/credit"] = credit
            # One event holding them all: add_scalar costs about 0.14 ms a tag.
            writer.file_writer.add_summary(Summary(value=[
                Summary.Value(tag=tag, simple_value=float(x)) for tag, x in selected.items()]), global_step)
            ultho_seconds += time.perf_counter() - tick

        report_progress(progress, args, iteration, num_iterations, global_step, sps, recent_returns,
                        f"{cluster}={format_value(choice)}" if selected is not None else
                        "fixed" if bandit is None else "random actions")

        if args.video_every and iteration % args.video_every == 0 and iteration != num_iterations:
            path = video_path(run_dir, f"iteration{iteration}", global_step)
            evaluate(sac.actor, dataclasses.replace(args, eval_episodes=1), device, path)
            log_video(tracker, path)
        if iteration % args.checkpoint_every == 0 or iteration == num_iterations:
            writer.flush()  # the events up to the checkpoint reach the disk first: a kill after it must not lose them
            save_checkpoint(checkpoint_path, {
                "script": SCRIPT, "format": CHECKPOINT_FORMAT, "config": config,
                "settings": dataclasses.asdict(settings),
                "iteration": iteration, "global_step": global_step, "num_updates": num_updates,
                "elapsed": elapsed_before + time.time() - start_time, "ultho_seconds": ultho_seconds,
                "sac": sac.state_dict(), "bandit": bandit.state_dict() if bandit is not None else None,
                "last_utility": last_utility,
                # Only the rows in use, copied out (a view would save the whole preallocated buffer).
                "replay": {"rows": storage[:filled].to("cpu", copy=True), "position": position, "filled": filled},
                "envs": envs.state_dict(), "next_obs": next_obs,
                "episode_return": episode_return, "episode_length": episode_length,
                "recent_returns": list(recent_returns), "recent_lengths": list(recent_lengths),
                "rng": rng_state(device, action_rng),
            })
    progress.close()

    wall_time = elapsed_before + time.time() - start_time
    final_video = video_path(run_dir, "final", global_step) if args.capture_video and diverged is None else None
    eval_returns = evaluate(sac.actor, args, device, final_video) if args.eval_episodes > 0 and diverged is None else []
    if eval_returns:
        writer.add_scalar("eval/return", float(np.mean(eval_returns)), global_step)
    writer.close()
    log_video(tracker, final_video)
    stop_tracking(tracker, diverged)
    write_summary(run_dir, args, config, settings, tuned, bandit, global_step,
                  num_iterations if diverged is None else diverged["iteration"], wall_time,
                  ultho_seconds, device, recent_returns, recent_lengths, eval_returns, diverged)
    if diverged is not None:
        stop_non_finite(diverged, settings, tuned, checkpoint_path)


def evaluate(actor: Actor, args: Args, device: torch.device, video_path: Optional[str] = None) -> list[float]:
    """Returns of --eval-episodes fresh episodes (environment seeds unused in training) of the deterministic
    policy (tanh of the mean, SAC's usual evaluation), up to 16 environments stepped in lockstep; with video_path,
    the first episode is recorded there."""
    returns: list[float] = []
    while len(returns) < args.eval_episodes:
        n = min(args.eval_episodes - len(returns), 16)
        record = video_path is not None and not returns
        envs = [make_env(args.env_id, render=record and k == 0) for k in range(n)]
        obs = np.stack([env.reset(seed=episode_seed(args.seed, 1, len(returns) + k))[0] for k, env in enumerate(envs)])
        frames = [envs[0].render()] if record else []
        total, running = np.zeros(n), np.ones(n, dtype=bool)
        while running.any():
            with torch.no_grad():
                action = actor.mean_action(torch.from_numpy(obs).to(device)).cpu().numpy()
            for k in np.flatnonzero(running):
                obs[k], reward, terminated, truncated, _ = envs[k].step(action[k])
                total[k] += reward
                running[k] = not (terminated or truncated)
                if record and k == 0:
                    frames.append(envs[0].render())
        for env in envs:
            env.close()
        if record:
            write_video(video_path, frames, VIDEO_FPS)
        returns += total.tolist()
    return returns


def evaluate_run(args: Args, checkpoint: dict) -> None:
    """--evaluate: the actor of the run's checkpoint on the final evaluation's episodes, reported on stdout."""
    if args.torch_threads > 0:
        torch.set_num_threads(args.torch_threads)
    device = torch.device("cuda" if torch.cuda.is_available() and args.cuda else "cpu")
    env = make_env(args.env_id)
    space = env.action_space
    actor = Actor(env.observation_space.shape[0], space.shape[0], space.low, space.high).to(device)
    env.close()
    actor.load_state_dict(checkpoint["sac"]["actor"])
    path = video_path(args.evaluate, "evaluate", checkpoint["global_step"]) if args.capture_video else None
    report_evaluation(args, checkpoint, evaluate(actor, args, device, path), path)


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


def check_renderer(env_id: str) -> None:
    """--capture-video needs a frame: rendered here once, so a machine without an off-screen OpenGL is told now."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = make_env(env_id, render=True)
            env.reset(seed=0)
            frame = env.render()
            env.close()
        if not (isinstance(frame, np.ndarray) and frame.ndim == 3):
            raise RuntimeError(f"render() returned {type(frame).__name__}")
    except Exception as err:  # noqa: BLE001  (no OpenGL library, no display, ...)
        reason = (str(err).splitlines() or [""])[0]
        raise UsageError(f"--capture-video: {env_id} cannot be rendered here with MUJOCO_GL="
                         f"{os.environ.get('MUJOCO_GL')} ({err.__class__.__name__}: {reason}); install Debian's "
                         "libegl1, libegl-mesa0 and libgl1-mesa-dri for EGL, or libosmesa6 for OSMesa") from None


def check_env_id(env_id: str) -> None:
    """A suite task (checked against the suite's list, so no task is built), else a registered gymnasium
    environment with a Box action space and a state-vector observation (constructed, never reset)."""
    domain, _, task = env_id.partition("-")
    if (domain, task) in suite.ALL_TASKS:
        return
    try:
        gym.spec(env_id)
    except gym.error.Error:
        raise UsageError(f"--env-id {env_id}: neither a DeepMind Control Suite task (DOMAIN-TASK, e.g. cheetah-run "
                         "or walker-walk; dm_control.suite.ALL_TASKS lists them) nor a registered gymnasium "
                         "environment") from None
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            env = make_env(env_id)
    except Exception as err:  # noqa: BLE001  (a missing dependency, for example)
        reason = (str(err).splitlines() or [""])[0]
        raise UsageError(f"--env-id {env_id}: cannot be constructed ({err.__class__.__name__}: {reason})") from None
    action_space, observation_space = env.action_space, env.observation_space
    env.close()
    if not isinstance(action_space, gym.spaces.Box):
        raise UsageError(f"--env-id {env_id}: its action space {action_space} is not continuous (Box)")
    if not (isinstance(observation_space, gym.spaces.Box) and len(observation_space.shape) == 1):
        raise UsageError(f"--env-id {env_id}: its observation space {observation_space} is not a state vector")


def check_setting(name: str, value, where: str) -> None:
    if name in ("batch_size", "policy_frequency", "target_network_frequency"):
        if isinstance(value, bool) or not isinstance(value, int) or value <= 0:
            raise UsageError(f"{where}: {name} must be a positive integer, got {value!r}")
    elif name in ("q_lr", "policy_lr"):
        if not (math.isfinite(value) and value > 0):
            raise UsageError(f"{where}: {name} must be positive, got {value!r}")
    elif not (math.isfinite(value) and 0 < value <= 1):  # tau, gamma
        raise UsageError(f"{where}: {name} must be in (0, 1], got {value!r}")


def checked_search_space(args: Args) -> dict[str, list]:
    """The search space from --ultho-clusters, each value checked as a setting it would override."""
    try:
        space = parse_clusters(list(args.ultho_clusters), SEARCH_SPACE, allowed=TUNABLE)
    except ValueError as err:
        raise UsageError(f"--ultho-clusters: {err}") from None
    for name, values in space.items():
        for value in values:
            check_setting(name, value, f"--ultho-clusters {name}")
    return space


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
        # The environments, the iterations and the replay buffer are carried over.
        for name in ("env_id", "num_envs", "ultho_interval", "buffer_size"):
            if getattr(args, name) != source[name]:
                raise UsageError(f"--init-from {args.init_from}: its {name} is {source[name]!r}, this run's "
                                 f"--{name.replace('_', '-')} {getattr(args, name)!r}")
        if args.total_timesteps // args.ultho_interval <= checkpoint["iteration"]:
            raise UsageError(f"--total-timesteps {args.total_timesteps}: the checkpoint of --init-from "
                             f"{args.init_from} is already at step {checkpoint['global_step']}")
    check_output_options(args)
    check_env_id(args.env_id)
    if args.capture_video:
        check_renderer(args.env_id)
    for name in ("num_envs", "total_timesteps", "buffer_size", "ultho_interval", "checkpoint_every"):
        if getattr(args, name) <= 0:
            raise UsageError(f"--{name.replace('_', '-')} must be positive, got {getattr(args, name)}")
    if args.torch_threads < 0:
        raise UsageError(f"--torch-threads must be >= 0 (0: one per core), got {args.torch_threads}")
    for name in ("learning_starts", "eval_episodes"):
        if getattr(args, name) < 0:
            raise UsageError(f"--{name.replace('_', '-')} must be >= 0, got {getattr(args, name)}")
    if args.ultho_interval % args.num_envs:
        raise UsageError(f"--ultho-interval {args.ultho_interval} is not a multiple of --num-envs {args.num_envs}")
    if args.total_timesteps < args.ultho_interval:
        raise UsageError(f"--total-timesteps {args.total_timesteps} is less than one iteration "
                         f"(--ultho-interval {args.ultho_interval} steps)")
    if args.buffer_size < args.num_envs:
        raise UsageError(f"--buffer-size {args.buffer_size} holds less than one step of --num-envs {args.num_envs}")
    for name in TUNABLE:
        check_setting(name, getattr(args, name), f"--{name.replace('_', '-')}")
    if not (math.isfinite(args.alpha) and args.alpha >= 0):
        raise UsageError(f"--alpha must be a finite number >= 0, got {args.alpha}")
    space = None
    if args.ultho:
        space = checked_search_space(args)
        if not (math.isfinite(args.ultho_c) and args.ultho_c >= 0):
            raise UsageError(f"--ultho-c must be a finite number >= 0, got {args.ultho_c}")
        if args.ultho_window < 1:
            raise UsageError(f"--ultho-window must be >= 1, got {args.ultho_window}")
        if not (math.isfinite(args.ultho_exp3_eta) and args.ultho_exp3_eta > 0):
            raise UsageError(f"--ultho-exp3-eta must be a finite number > 0, got {args.ultho_exp3_eta}")
    if args.resume is None and args.evaluate is None:
        if os.sep in args.run_name or args.run_name in ("", ".", ".."):
            raise UsageError(f"--run-name {args.run_name!r} is not a plain directory name")
        run_dir = os.path.join(args.runs_dir, args.run_name)
        # --init-from may continue a run of this script in its own directory (its logs go on from the checkpoint).
        if os.path.exists(run_dir) and not (args.init_from is not None and (
                os.path.abspath(run_dir) == os.path.abspath(args.init_from) or is_run_of_this_script(run_dir))):
            raise UsageError(f"run directory {run_dir} already exists: pass --resume {run_dir} or another --run-name")
    return space, checkpoint


def is_run_of_this_script(run_dir: str) -> bool:
    try:
        checkpoint = torch.load(os.path.join(run_dir, "checkpoint.pt"), map_location="cpu", weights_only=False)
        return checkpoint["script"] == SCRIPT
    except Exception:  # noqa: BLE001  (missing or foreign: not a run to continue)
        return False


def rng_state(device: torch.device, action_rng: np.random.Generator) -> dict:
    return {"python": random.getstate(), "numpy": np.random.get_state(), "torch": torch.get_rng_state(),
            "cuda": torch.cuda.get_rng_state_all() if device.type == "cuda" else None,
            "actions": action_rng.bit_generator.state}


def restore_rng(state: dict, device: torch.device, action_rng: np.random.Generator) -> None:
    random.setstate(state["python"])
    np.random.set_state(state["numpy"])
    torch.set_rng_state(state["torch"])
    if device.type == "cuda" and state["cuda"] is not None:
        torch.cuda.set_rng_state_all(state["cuda"])  # actions and batches are drawn on the device
    action_rng.bit_generator.state = state["actions"]


def stop_non_finite(diverged: dict, settings: Settings, tuned: list[str], checkpoint_path: str) -> None:
    """Exit status 1 with where the run diverged and the settings in force, once summary.json has recorded the
    divergence (the tools count the run as finished); the last checkpoint stays as it was."""
    last = (f"the last good checkpoint is {checkpoint_path}" if os.path.exists(checkpoint_path)
            else "no checkpoint was written")
    print(f"{SCRIPT}: error: non-finite {diverged['what']} at iteration {diverged['iteration']} (step "
          f"{diverged['global_step']}) with {', '.join(f'{n}={format_value(getattr(settings, n))}' for n in tuned)}; "
          f"stopped, summary.json records the divergence, {last}", file=sys.stderr)
    sys.exit(1)


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
    """Atomically: written to a sibling file, fsynced, renamed over the last one. Serialized straight to the
    file, not through memory first: the replay buffer is most of it (docs/dmc.md has its size)."""
    tmp = f"{path}.tmp"
    with open(tmp, "wb") as f:
        torch.save(checkpoint, f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def atomic_write_bytes(path: str, data: bytes) -> None:
    tmp = f"{path}.tmp"
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def atomic_save_json(path: str, obj: dict) -> None:
    atomic_write_bytes(path, (json.dumps(obj, indent=2, allow_nan=False) + "\n").encode())


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


def write_summary(run_dir: str, args: Args, config: dict, settings: Settings, tuned: list[str],
                  bandit: Optional[ULTHO], global_step: int, num_iterations: int, wall_time: float,
                  ultho_seconds: float, device: torch.device, recent_returns: deque, recent_lengths: deque,
                  eval_returns: list[float], diverged: Optional[dict]) -> None:
    """summary.json, with the PPO scripts' keys (docs/scripts.md)."""
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
        "device": str(device),
        "final_score": float(np.mean(recent_returns)) if recent_returns else None,
        "final_score_episodes": len(recent_returns),
        "final_episode_length": float(np.mean(recent_lengths)) if recent_lengths else None,
        "eval": {
            "episodes": len(eval_returns),
            "mean_return": float(np.mean(eval_returns)) if eval_returns else None,
            "std_return": float(np.std(eval_returns)) if eval_returns else None,
            "returns": eval_returns,
        },
        "settings_in_force": {name: getattr(settings, name) for name in tuned},
        "bandit": None if bandit is None else bandit.summary("min_q"),
    }
    atomic_save_json(os.path.join(run_dir, "summary.json"), summary)
    if not args.quiet and diverged is None:  # else the error line says where it stopped
        score = summary["final_score"]
        print(f"[{SCRIPT}] done: {global_step} steps in {wall_time:.0f}s, final score "
              f"{'-' if score is None else f'{score:.3f}'}, summary in {run_dir}/summary.json", flush=True)


if __name__ == "__main__":
    try:
        main(parse_args())
    except UsageError as err:
        print(f"{SCRIPT}: error: {err}", file=sys.stderr)
        sys.exit(2)

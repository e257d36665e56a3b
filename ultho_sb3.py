"""ULTHO for Stable-Baselines3: a callback that tunes PPO's or A2C's settings inside one ``learn()``.

::

    from stable_baselines3 import PPO
    from ultho_sb3 import ULTHOCallback

    model = PPO("MlpPolicy", "CartPole-v1", tensorboard_log="runs")
    callback = ULTHOCallback({"learning_rate": [1e-4, 3e-4, 1e-3], "n_epochs": [5, 10, 20]})
    model.learn(200_000, callback=callback)
    model.save("ppo_cartpole")
    callback.save("ppo_cartpole")          # the bandit, beside the model: ppo_cartpole.ultho.json

    model = PPO.load("ppo_cartpole", env=model.get_env())
    callback = ULTHOCallback.load("ppo_cartpole")
    model.learn(200_000, callback=callback, reset_num_timesteps=False)   # the same bandit goes on

``ULTHOCallback(space, save_path="ckpt/ppo", save_every=10)`` also checkpoints both every 10 rollouts;
``latest_checkpoint("ckpt/ppo")`` is the path to load after a crash.

At the end of every rollout, before SB3 runs ``train()`` on it, the callback credits the previous choice
with the rollout's mean value estimate (``utility="return"``: its mean GAE return), lets the bandit
(``ultho_bandit.ULTHO``; extra keyword arguments such as ``strategy``, ``credit`` or ``scale`` go to it) select
one cluster and one value, and puts that value in force for the coming ``train()``. Every other setting keeps
the value it had. Clusters: ``learning_rate``, ``batch_size``, ``n_epochs``, ``vf_coef``, ``ent_coef``,
``clip_range``, ``max_grad_norm``, ``gae_lambda``; A2C has no ``batch_size``, ``n_epochs`` or ``clip_range``.
The bandit's ``scalars()``, the credit and the settings in force (``hparams/<name>``) go through SB3's logger, so
they appear in the TensorBoard run SB3 writes.

``docs/sb3.md`` explains what is credited when, how each setting is put in force (SB3 resets the learning
rate and the clip range from schedules in every ``train()``), saving and resuming, and the callback's cost.
"""

from __future__ import annotations

import contextlib
import glob
import io
import json
import os
import time
from typing import Any, Callable, Literal, Mapping, Sequence

import numpy as np

with contextlib.redirect_stderr(io.StringIO()):
    # SB3 imports the unmaintained gym package where it is installed (procgen needs it), and gym prints a
    # deprecation notice on import; importing it here first keeps stderr for real messages.
    with contextlib.suppress(ImportError):
        import gym  # noqa: F401
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
from stable_baselines3.common.utils import FloatSchedule, update_learning_rate

from ultho_bandit import ULTHO, Number, format_value

STATE_FORMAT = 1
STATE_SUFFIX = ".ultho.json"
Utility = Literal["value", "return", "authors-return"]

_RULES: dict[str, tuple[Callable[[Number], bool], str]] = {
    "learning_rate": (lambda v: v > 0, "a number > 0"),
    "batch_size": (lambda v: isinstance(v, int) and v >= 1, "an integer >= 1"),
    "n_epochs": (lambda v: isinstance(v, int) and v >= 1, "an integer >= 1"),
    "vf_coef": (lambda v: v >= 0, "a number >= 0"),
    "ent_coef": (lambda v: v >= 0, "a number >= 0"),
    "clip_range": (lambda v: v > 0, "a number > 0"),
    "max_grad_norm": (lambda v: v > 0, "a number > 0"),
    "gae_lambda": (lambda v: 0 <= v <= 1, "a number in [0, 1]"),
}
CLUSTERS = tuple(_RULES)
"""Every setting the callback can tune, by its SB3 name."""
PPO_ONLY = ("batch_size", "n_epochs", "clip_range")
"""The clusters A2C lacks: it takes one gradient step over the whole rollout and does not clip its policy."""


def supported_clusters(model: Any) -> tuple[str, ...]:
    """The clusters ``model`` can be tuned on: all of :data:`CLUSTERS` for PPO, those but :data:`PPO_ONLY`
    for A2C (a setting is supported when the on-policy algorithm has it as an attribute)."""
    return tuple(name for name in CLUSTERS if hasattr(model, name))


def state_path(path: str | os.PathLike) -> str:
    """Where :meth:`ULTHOCallback.save` puts the bandit for the path given to ``model.save``:
    ``run/ppo`` and ``run/ppo.zip`` give ``run/ppo.ultho.json``; a path ending in ``.json`` is used as is."""
    path = os.fspath(path)
    if path.endswith(".json"):
        return path
    return path.removesuffix(".zip") + STATE_SUFFIX


def checkpoint_path(save_path: str | os.PathLike, step: int) -> str:
    """The path (for ``PPO.load`` and :meth:`ULTHOCallback.load`) of the checkpoint ``save_every`` writes at
    ``step``: ``<save_path>_<step>_steps``, as SB3's CheckpointCallback names its files."""
    return f"{os.fspath(save_path)}_{step}_steps"


def latest_checkpoint(save_path: str | os.PathLike) -> str | None:
    """The newest checkpoint under ``save_path`` whose model and bandit are both on disk (a run killed between
    the two writes leaves the one before), or None."""
    found = []
    for state in glob.glob(glob.escape(os.fspath(save_path)) + "_*_steps" + STATE_SUFFIX):
        base = state.removesuffix(STATE_SUFFIX)
        step = base.removeprefix(os.fspath(save_path) + "_").removesuffix("_steps")
        if step.isdigit() and os.path.exists(base + ".zip"):
            found.append((int(step), base))
    return max(found)[1] if found else None


def _atomic_write_json(path: str, obj: dict) -> None:
    # A kill mid-save must leave the previous state readable: write a sibling, fsync, rename over. (The tools'
    # ultho_runs.atomic_write_json does the same; this module installs on its own, so it keeps a copy.)
    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        f.write(json.dumps(obj, indent=2, allow_nan=False) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def _progress_remaining(model: OnPolicyAlgorithm) -> float:
    # What learn() passes to the coming train(): it updates the progress only after this callback has run.
    if model._total_timesteps <= 0:  # before the first learn()
        return model._current_progress_remaining
    return 1.0 - model.num_timesteps / model._total_timesteps


def setting_in_force(model: OnPolicyAlgorithm, name: str) -> Number:
    """The value of setting ``name`` that the model's next ``train()`` uses (a schedule evaluated at the
    progress that ``train()`` will see)."""
    if name == "learning_rate":
        return float(model.lr_schedule(_progress_remaining(model)))
    if name == "clip_range":
        return float(model.clip_range(_progress_remaining(model)))
    if name == "gae_lambda":
        return float(model.rollout_buffer.gae_lambda)
    if name in ("batch_size", "n_epochs"):
        return int(getattr(model, name))
    return float(getattr(model, name))


def apply_setting(model: OnPolicyAlgorithm, name: str, value: Number) -> None:
    """Puts ``value`` in force for the model's next ``train()`` and for ``model.save`` / ``load``.

    ``train()`` recomputes the learning rate from ``model.lr_schedule`` and the clip range from
    ``model.clip_range`` (both schedules of the training progress), so those are replaced by constants;
    the rest are plain attributes. A new ``gae_lambda`` only affects advantages computed after it is set.
    """
    if name == "learning_rate":
        model.learning_rate = value
        model.lr_schedule = FloatSchedule(float(value))
        update_learning_rate(model.policy.optimizer, float(value))
    elif name == "clip_range":
        model.clip_range = FloatSchedule(float(value))
    elif name == "gae_lambda":
        model.gae_lambda = float(value)
        model.rollout_buffer.gae_lambda = float(value)
    elif name in ("batch_size", "n_epochs"):
        setattr(model, name, int(value))
    elif name in CLUSTERS:
        setattr(model, name, float(value))
    else:
        raise ValueError(f"ULTHOCallback: unknown cluster {name!r}; known: {', '.join(CLUSTERS)}")


class ULTHOCallback(BaseCallback):
    """In-run hyperparameter optimisation of an SB3 on-policy algorithm (PPO, A2C) with the ULTHO bandit.

    Args:
        search_space: ordered ``{cluster: [candidate values]}``, clusters among :data:`CLUSTERS`.
        c: the bandit's exploration coefficient (Eqs. 4-5). Paper grid: 1, 5.
        window: W, the number of recent credits averaged into a utility (Eq. 6). Paper grid: 10, 50, 100.
        utility: what credits a choice: ``"value"`` (the mean value estimate over the next rollout, collected
            by the policy that choice trained; the paper's signal), ``"return"`` (that rollout's mean GAE
            return) or ``"authors-return"`` (the authors' public code: the mean GAE return of the rollout the
            choice is made on, credited at once; the first choice of a training is withdrawn uncredited).
        save_path, save_every: every ``save_every`` rollouts (0: never) and when ``learn()`` ends, the model
            and the bandit are saved at :func:`checkpoint_path` ``(save_path, step)``, each atomically, so a
            crash or kill loses at most ``save_every`` rollouts; :func:`latest_checkpoint` finds the newest.
        verbose: SB3's callback verbosity; 1 prints each choice.
        **bandit_options: passed on to ``ULTHO(search_space, c=c, window=window, **bandit_options)``
            (``strategy``, ``credit``, ``scale``, ``seed``, ...); the utility measured at each rollout's end is
            also the ``before`` of the next ``select()``, the baseline of ``credit="improvement"``.

    Raises:
        ValueError: an unknown cluster, a value a setting cannot take, a bad ``utility`` or a bandit option
            ``ULTHO`` refuses, here; a cluster the algorithm lacks (A2C's ``batch_size``), a ``batch_size``
            that does not divide the rollout (``n_steps * n_envs``), an algorithm that is not on-policy, or a
            loaded state that does not belong to the model, when ``learn()`` starts, before any training.
    """

    def __init__(self, search_space: Mapping[str, Sequence[Number]], c: float = 5.0, window: int = 10,
                 utility: Utility = "value", save_path: str | os.PathLike | None = None, save_every: int = 0,
                 verbose: int = 0, **bandit_options: Any) -> None:
        super().__init__(verbose)
        if isinstance(save_every, bool) or not isinstance(save_every, int) or save_every < 0:
            raise ValueError(f"ULTHOCallback: save_every={save_every!r} must be an integer >= 0 (rollouts)")
        if save_every > 0 and save_path is None:
            raise ValueError("ULTHOCallback: save_every needs a save_path to write the checkpoints to")
        if isinstance(search_space, Mapping):
            for name in search_space:
                if name not in _RULES:
                    raise ValueError(f"ULTHOCallback: unknown cluster {name!r}; known: {', '.join(CLUSTERS)}")
        if utility not in ("value", "return", "authors-return"):
            raise ValueError(f"ULTHOCallback: utility={utility!r} must be 'value', 'return' or 'authors-return'")
        if utility == "authors-return" and bandit_options.get("credit") == "improvement":
            raise ValueError("ULTHOCallback: credit='improvement' does not go with utility='authors-return' (a "
                             "choice would be measured against its own credit)")
        try:
            self.bandit = ULTHO(search_space, c=c, window=window, **bandit_options)
        except ValueError as err:
            raise ValueError(f"ULTHOCallback: {err}") from None
        for name, values in self.bandit.search_space.items():
            accepts, expected = _RULES[name]
            for value in values:
                if not accepts(value):
                    raise ValueError(f"ULTHOCallback: cluster {name!r}: value {format_value(value)} is not "
                                     f"{expected}")
        self.utility: Utility = utility
        self.chosen: dict[str, Number] = {}
        """The latest value ULTHO chose for each cluster chosen so far (the others keep the model's own)."""
        self.seconds = 0.0
        """Wall time spent in the callback's own work (credit, select, apply, record), for its share of a run."""
        self.save_path = None if save_path is None else os.fspath(save_path)
        self.save_every = save_every
        self._saved_at_step: int | None = None  # set by load(): the model must be at this step
        self._rollouts = 0  # rollout ends seen, for save_every
        self._checkpointed_step: int | None = None
        self._first_withdrawn = False  # authors-return: the first choice of a training is never credited

    # ------------------------------------------------------------------ SB3's hooks
    def _init_callback(self) -> None:
        model = self.model
        algorithm = type(model).__name__
        if not isinstance(model, OnPolicyAlgorithm):
            raise ValueError(f"ULTHOCallback: {algorithm} is not an on-policy algorithm; ULTHO tunes PPO and A2C")
        supported = supported_clusters(model)
        for name in self.bandit.cluster_names:
            if name not in supported:
                raise ValueError(f"ULTHOCallback: {algorithm} has no {name!r} setting; for {algorithm} the "
                                 f"clusters can be: {', '.join(supported)}")
        rollout = model.n_steps * model.n_envs
        for batch_size in self.bandit.search_space.get("batch_size", []):
            if rollout % batch_size != 0:
                raise ValueError(f"ULTHOCallback: batch_size {batch_size} does not divide the rollout of "
                                 f"n_steps * n_envs = {model.n_steps} * {model.n_envs} = {rollout}")
            if batch_size == 1 and getattr(model, "normalize_advantage", False):
                raise ValueError("ULTHOCallback: batch_size 1 cannot normalize advantages; use >= 2 or "
                                 "normalize_advantage=False")
        if self._saved_at_step is not None and model.num_timesteps != self._saved_at_step:
            raise ValueError(f"ULTHOCallback: the bandit was saved at step {self._saved_at_step} but the model "
                             f"is at step {model.num_timesteps}; load the model saved with it and continue with "
                             f"learn(..., reset_num_timesteps=False)")
        self._saved_at_step = None

    def _on_step(self) -> bool:
        return True

    def _on_rollout_start(self) -> None:
        # Between a train() and the next rollout, model and bandit are what learn() would leave if it returned.
        if self.save_every and self._rollouts and self._rollouts % self.save_every == 0:
            self._checkpoint()

    def _on_training_end(self) -> None:
        if self.save_every:
            self._checkpoint()

    def _checkpoint(self) -> None:
        """The model, then the bandit, each written atomically, at checkpoint_path(save_path, step)."""
        step = self.model.num_timesteps
        if step == self._checkpointed_step:
            return
        base = checkpoint_path(self.save_path, step)
        os.makedirs(os.path.dirname(base) or ".", exist_ok=True)
        self.model.save(base + ".tmp.zip")
        os.replace(base + ".tmp.zip", base + ".zip")
        self.save(base)
        self._checkpointed_step = step

    def _on_rollout_end(self) -> None:
        tick = time.perf_counter()
        model, buffer = self.model, self.model.rollout_buffer
        # Measured now, before this rollout's choice takes effect: it credits the previous choice and is the
        # baseline of the bandit's credit="improvement".
        measured = float(np.mean(buffer.values if self.utility == "value" else buffer.returns, dtype=np.float64))
        credit = None
        if self.bandit.pending is not None:
            credit = measured
            self.bandit.update(credit)
        name, value = self.bandit.select(before=measured)
        if self.utility == "authors-return":  # the authors' code credits the choice made now, except the first
            if self._first_withdrawn:
                credit = measured
                self.bandit.update(credit)
            else:
                self.bandit.withdraw()
                self._first_withdrawn = True
        apply_setting(model, name, value)
        self.chosen[name] = value
        if name == "gae_lambda":
            # SB3 computed this rollout's advantages before calling us; redo them with the new lambda.
            buffer.compute_returns_and_advantage(last_values=self.locals["values"], dones=self.locals["dones"])
        self._rollouts += 1
        self._record(credit)
        if self.verbose >= 1:
            print(f"ULTHO step {model.num_timesteps}: {name}={format_value(value)}"
                  + ("" if credit is None else f" (previous choice credited {credit:.4g})"))
        self.seconds += time.perf_counter() - tick

    def _record(self, credit: float | None) -> None:
        """The bandit's scalars, the credit and the settings in force, written with SB3's next dump."""
        logger = self.logger
        for tag, x in self.bandit.scalars().items():
            per_arm = tag.count("/") >= 2  # ultho/ucb/<cluster>[/<value>]: too many for SB3's console table
            logger.record(tag, x, exclude=("stdout", "log") if per_arm else None)
        if credit is not None:
            logger.record("ultho/credit", credit)
        for name in self.bandit.cluster_names:
            logger.record(f"hparams/{name}", setting_in_force(self.model, name))

    # ------------------------------------------------------------------ read-outs
    @property
    def settings_in_force(self) -> dict[str, Number]:
        """``{cluster: value}`` the model's next ``train()`` uses, for every cluster of the search space."""
        return {name: setting_in_force(self.model, name) for name in self.bandit.cluster_names}

    # ------------------------------------------------------------------ saving and loading
    def state_dict(self) -> dict[str, Any]:
        """Everything :meth:`load` needs, JSON-serialisable: the bandit's state (its options and a pending
        choice included), the utility, the values chosen so far and the model's step."""
        return {
            "format": STATE_FORMAT,
            "kind": "ultho_sb3.ULTHOCallback",
            "num_timesteps": self.model.num_timesteps if hasattr(self, "model") else 0,
            "utility": self.utility,
            "save_path": self.save_path,
            "save_every": self.save_every,
            "chosen": dict(self.chosen),
            "first_withdrawn": self._first_withdrawn,
            "bandit": self.bandit.state_dict(),
        }

    def save(self, path: str | os.PathLike) -> str:
        """Writes the state atomically beside ``model.save(path)`` (see :func:`state_path`); returns the file."""
        target = state_path(path)
        _atomic_write_json(target, self.state_dict())
        return target

    @classmethod
    def load(cls, path: str | os.PathLike, verbose: int = 0) -> "ULTHOCallback":
        """The callback :meth:`save` wrote for ``path``. Use it with the model saved at the same time (the
        settings in force are the model's attributes, which ``model.save`` keeps) and
        ``learn(..., reset_num_timesteps=False)``; its pending choice is credited at the first rollout's end.

        Raises:
            ValueError: the file is missing, unreadable or not a saved ULTHOCallback.
        """
        target = state_path(path)
        try:
            with open(target) as f:
                state = json.load(f)
        except (OSError, ValueError) as err:
            raise ValueError(f"ULTHOCallback.load: cannot read {target}: {err}") from None
        if not isinstance(state, dict) or state.get("kind") != "ultho_sb3.ULTHOCallback":
            raise ValueError(f"ULTHOCallback.load: {target} is not a saved ULTHOCallback")
        if state.get("format") != STATE_FORMAT:
            raise ValueError(f"ULTHOCallback.load: {target} has format {state.get('format')!r}, not {STATE_FORMAT}")
        try:
            bandit = ULTHO.from_state_dict(state["bandit"])
            callback = cls(bandit.search_space, utility=state["utility"], save_path=state["save_path"],
                           save_every=state["save_every"], verbose=verbose, **bandit.options())
            callback.bandit = bandit
            chosen = {str(name): value for name, value in state["chosen"].items()}
            steps = state["num_timesteps"]
        except (KeyError, TypeError, AttributeError, ValueError) as err:
            raise ValueError(f"ULTHOCallback.load: {target} is malformed: {err}") from None
        if any(name not in callback.bandit.search_space or value not in callback.bandit.search_space[name]
               for name, value in chosen.items()) or not isinstance(steps, int) or steps < 0:
            raise ValueError(f"ULTHOCallback.load: {target} is malformed: chosen values {chosen} or step {steps!r}")
        callback.chosen = chosen
        callback._first_withdrawn = bool(state.get("first_withdrawn", False))
        callback._saved_at_step = steps
        return callback

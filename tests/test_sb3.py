"""ultho_sb3.ULTHOCallback with real Stable-Baselines3 PPO and A2C on real CartPole environments, tiny budgets.

What is checked against SB3 itself rather than against the callback's own bookkeeping: the optimizer's
learning rate at every gradient step (a torch step hook), the number of gradient steps of every train(), the
tags in SB3's own TensorBoard event file, and models trained with a setting chosen by the callback against
models constructed with that setting.
"""

import json
import os
import random
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import torch
from stable_baselines3 import A2C, DQN, PPO
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy

from helpers import REPO, scalars
from ultho_bandit import ULTHO
from ultho_sb3 import (CLUSTERS, PPO_ONLY, ULTHOCallback, checkpoint_path, latest_checkpoint, state_path,
                       supported_clusters)

N_STEPS, N_ENVS = 32, 2
ROLLOUT = N_STEPS * N_ENVS


@pytest.fixture(autouse=True, scope="module")
def one_torch_thread():
    """SB3 trains in this process; one thread suffices for these networks, and on shared cores torch's default
    of one per core made PPO ten times slower."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def cartpole(n_envs: int = N_ENVS):
    return make_vec_env("CartPole-v1", n_envs=n_envs, seed=0)


def ppo(device: str = "cpu", **settings) -> PPO:
    settings = {"n_steps": N_STEPS, "batch_size": ROLLOUT, "seed": 0, **settings}
    return PPO("MlpPolicy", cartpole(), device=device, **settings)


def a2c(**settings) -> A2C:
    return A2C("MlpPolicy", cartpole(), n_steps=8, seed=0, device="cpu", **settings)


def parameters(model) -> list[torch.Tensor]:
    return [p.detach().cpu().clone() for p in model.policy.parameters()]


def identical(a: list[torch.Tensor], b: list[torch.Tensor]) -> bool:
    return len(a) == len(b) and all(torch.equal(x, y) for x, y in zip(a, b))


def record_gradient_steps(model) -> list[tuple[int, float]]:
    """(model.num_timesteps, the optimizer's learning rate) at every optimizer step, from torch itself."""
    steps: list[tuple[int, float]] = []
    model.policy.optimizer.register_step_pre_hook(
        lambda optimizer, args, kwargs: steps.append((model.num_timesteps, optimizer.param_groups[0]["lr"])))
    return steps


def expected_settings(space: dict, initial: dict, tags: dict) -> dict[int, dict]:
    """{step: settings in force for the train() after that rollout}, replayed from the choices SB3 logged."""
    names, in_force, out = list(space), dict(initial), {}
    clusters, indices, values = (dict(tags[f"ultho/{t}"]) for t in ("selected_cluster", "selected_value_index",
                                                                      "selected_value"))
    for step in sorted(clusters):
        name = names[int(clusters[step])]
        value = space[name][int(indices[step])]
        assert values[step] == pytest.approx(value, rel=1e-6)
        in_force[name] = value
        out[step] = dict(in_force)
    return out


# ---------------------------------------------------------------------------------------------------- PPO
PPO_SPACE = {"learning_rate": [1e-4, 1e-3], "n_epochs": [1, 3], "batch_size": [16, 64], "clip_range": [0.1, 0.3]}
PPO_ROLLOUTS = 10


@pytest.fixture(scope="module", params=["cpu", "cuda"])
def ppo_run(request, tmp_path_factory):
    """One PPO run with the callback and a TensorBoard log: what SB3 did at every gradient step, and its tags."""
    if request.param == "cuda" and not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    logdir = tmp_path_factory.mktemp("tb")
    model = ppo(device=request.param, n_epochs=2, tensorboard_log=str(logdir))
    initial = {"learning_rate": 3e-4, "n_epochs": 2, "batch_size": ROLLOUT, "clip_range": 0.2}  # PPO's defaults
    steps = record_gradient_steps(model)
    callback = ULTHOCallback(PPO_SPACE, c=5.0, window=10)
    model.learn(PPO_ROLLOUTS * ROLLOUT, callback=callback)
    tags = scalars(os.path.join(logdir, "PPO_1"))
    return {"model": model, "callback": callback, "steps": steps, "tags": tags,
            "expected": expected_settings(PPO_SPACE, initial, tags)}


def test_every_value_was_tried(ppo_run):
    """The rest of this module's PPO checks mean something only if every value was in force at some train()."""
    assert all(count >= 1 for counts in ppo_run["callback"].bandit.value_selections().values() for count in counts)
    assert sorted(ppo_run["expected"]) == [ROLLOUT * k for k in range(1, PPO_ROLLOUTS + 1)]


def test_optimizer_learning_rate_during_each_train_is_the_chosen_one(ppo_run):
    """SB3's train() resets the optimizer's lr from model.lr_schedule (SB3 issue 1336): setting
    model.learning_rate alone would leave every step at 3e-4."""
    by_train: dict[int, set[float]] = {}
    for step, lr in ppo_run["steps"]:
        by_train.setdefault(step, set()).add(lr)
    expected = {step: {s["learning_rate"]} for step, s in ppo_run["expected"].items()}
    assert by_train == expected
    assert {lr for lrs in by_train.values() for lr in lrs} == {1e-4, 1e-3}  # never PPO's own 3e-4


def test_gradient_steps_of_each_train_match_chosen_epochs_and_batch_size(ppo_run):
    counts: dict[int, int] = {}
    for step, _ in ppo_run["steps"]:
        counts[step] = counts.get(step, 0) + 1
    expected = {step: s["n_epochs"] * ROLLOUT // s["batch_size"] for step, s in ppo_run["expected"].items()}
    assert counts == expected
    assert len(set(expected.values())) >= 3  # 1, 3, 4 or 12 steps: the choices really changed the work


def test_clip_range_used_by_each_train_is_the_chosen_one(ppo_run):
    """train() evaluates model.clip_range, a schedule; SB3 logs the value it used as train/clip_range, which
    is written at the next rollout's dump (the last train's never is)."""
    used = dict(ppo_run["tags"]["train/clip_range"])
    expected = ppo_run["expected"]
    steps = sorted(expected)
    assert {step: pytest.approx(used[step], rel=1e-6) for step in steps[1:]} == \
        {step: expected[prev]["clip_range"] for prev, step in zip(steps, steps[1:])}


def test_tensorboard_event_file_holds_the_bandit_and_the_settings(ppo_run):
    tags, callback = ppo_run["tags"], ppo_run["callback"]
    ours = set(callback.bandit.scalars()) | {"ultho/credit"} | {f"hparams/{name}" for name in PPO_SPACE}
    assert ours <= set(tags)
    rollout_ends = [ROLLOUT * k for k in range(1, PPO_ROLLOUTS + 1)]
    for tag in ours - {"ultho/credit"}:
        assert [step for step, _ in tags[tag]] == rollout_ends, tag
    assert [step for step, _ in tags["ultho/credit"]] == rollout_ends[1:]  # the first choice has no predecessor
    for k, step in enumerate(rollout_ends):
        at = {tag: dict(series)[step] for tag, series in tags.items() if step in dict(series)}
        assert sum(at[f"ultho/count/{name}"] for name in PPO_SPACE) == k  # credited choices so far
        chosen = list(PPO_SPACE)[int(at["ultho/selected_cluster"])]
        assert at[f"ultho/ucb/{chosen}"] == max(at[f"ultho/ucb/{name}"] for name in PPO_SPACE)
        for name, value in ppo_run["expected"][step].items():
            assert at[f"hparams/{name}"] == pytest.approx(value, rel=1e-6)
    last = {tag: series[-1][1] for tag, series in tags.items()}
    assert {name: last[f"ultho/count/{name}"] for name in PPO_SPACE} == callback.bandit.selections()


@pytest.mark.parametrize("utility, field, options", [("value", "values", {}), ("return", "returns", {}),
                                                     ("value", "values", {"credit": "improvement"}),
                                                     ("authors-return", "returns", {})])
def test_credit_is_the_mean_value_estimate_of_the_next_rollout(utility, field, options):
    """Each rollout's end credits the previous choice with the mean of the rollout buffer's values; with
    utility="return", of its returns. That mean is also the baseline (select's `before`) of the choice made
    then, which credit="improvement" subtracts. Replaying the means on a fresh bandit gives the same state."""
    model = ppo()
    callback = ULTHOCallback({"vf_coef": [0.25, 0.5, 1.0]}, utility=utility, **options)
    means: list[float] = []

    class Snapshot(BaseCallback):  # runs after `callback` in the list: sees the buffer it credited
        def _on_step(self) -> bool:
            return True

        def _on_rollout_end(self) -> None:
            means.append(float(np.mean(getattr(self.model.rollout_buffer, field), dtype=np.float64)))

    model.learn(4 * ROLLOUT, callback=[callback, Snapshot()])
    replay = ULTHO({"vf_coef": [0.25, 0.5, 1.0]}, **options)
    for k, mean in enumerate(means):
        if utility == "authors-return":  # the choice made at a rollout's end takes that rollout's mean, but the first
            replay.select(before=mean)
            replay.update(mean) if k > 0 else replay.withdraw()
            continue
        if k > 0:
            replay.update(mean)
        replay.select(before=mean)
    assert replay.state_dict() == callback.bandit.state_dict()
    authors = utility == "authors-return"
    assert callback.bandit.num_selections == (3 if authors else 4)
    assert sum(callback.bandit.selections().values()) == 3 and (callback.bandit.pending is None) == authors


# ------------------------------------------------------------------------------- each setting, both algorithms
PPO_VALUES = {"learning_rate": 1e-3, "batch_size": 16, "n_epochs": 3, "vf_coef": 2.0, "ent_coef": 0.5,
              "clip_range": 0.001, "max_grad_norm": 0.01, "gae_lambda": 0.5}
A2C_VALUES = {name: value for name, value in PPO_VALUES.items() if name not in PPO_ONLY}


@pytest.fixture(scope="module")
def untouched():
    """Parameters after training with SB3's defaults and no callback, per algorithm."""
    cache = {}

    def trained(algorithm: str) -> list[torch.Tensor]:
        if algorithm not in cache:
            model = ppo() if algorithm == "PPO" else a2c()
            model.learn(2 * model.n_steps * model.n_envs)
            cache[algorithm] = parameters(model)
        return cache[algorithm]

    return trained


@pytest.mark.parametrize("algorithm, name, value", [("PPO", *item) for item in PPO_VALUES.items()]
                         + [("A2C", *item) for item in A2C_VALUES.items()])
def test_a_chosen_setting_trains_exactly_as_if_the_model_was_built_with_it(algorithm, name, value, untouched):
    """A one-value cluster makes the callback choose `value` for every train(); the model must then train
    exactly like one constructed with it, and unlike SB3's default. For ent_coef this is what users found
    missing when they changed it from a callback (SB3 issue 628); for learning_rate and clip_range what
    SB3's schedules undo (issue 1336); for gae_lambda the rollout's advantages must be recomputed."""
    build = ppo if algorithm == "PPO" else a2c
    tuned = build()
    tuned.learn(2 * tuned.n_steps * tuned.n_envs, callback=ULTHOCallback({name: [value]}))
    constructed = build(**{name: value})
    constructed.learn(2 * constructed.n_steps * constructed.n_envs)
    assert identical(parameters(tuned), parameters(constructed))
    assert not identical(parameters(tuned), untouched(algorithm))


A2C_SPACE = {"learning_rate": [1e-4, 1e-3], "ent_coef": [0.0, 0.1], "vf_coef": [0.25, 1.0],
             "max_grad_norm": [0.1, 0.5], "gae_lambda": [0.9, 1.0]}


def test_a2c_takes_one_gradient_step_per_rollout_at_the_chosen_learning_rate(tmp_path):
    model = a2c(tensorboard_log=str(tmp_path))
    steps = record_gradient_steps(model)
    rollout, rollouts = model.n_steps * model.n_envs, 12
    callback = ULTHOCallback(A2C_SPACE)
    model.learn(rollouts * rollout, callback=callback, log_interval=1)  # A2C's default dumps every 100th
    tags = scalars(os.path.join(tmp_path, "A2C_1"))
    initial = {"learning_rate": 7e-4, "ent_coef": 0.0, "vf_coef": 0.5, "max_grad_norm": 0.5, "gae_lambda": 1.0}
    expected = expected_settings(A2C_SPACE, initial, tags)
    assert steps == [(step, expected[step]["learning_rate"]) for step in sorted(expected)]
    assert len(steps) == rollouts and {lr for _, lr in steps} >= {1e-4, 1e-3}
    assert set(callback.bandit.scalars()) | {f"hparams/{name}" for name in A2C_SPACE} <= set(tags)


def test_supported_clusters_per_algorithm():
    assert supported_clusters(ppo()) == CLUSTERS
    assert supported_clusters(a2c()) == tuple(name for name in CLUSTERS if name not in PPO_ONLY)
    assert set(PPO_ONLY) == {"batch_size", "n_epochs", "clip_range"}


# ------------------------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("space, options, named", [
    ({"gamma": [0.9, 0.99]}, {}, "'gamma'"),
    ({"minibatch_size": [64]}, {}, "'minibatch_size'"),
    ({}, {}, "empty search space"),
    ({"learning_rate": []}, {}, "no candidate values"),
    ({"learning_rate": [-1e-3]}, {}, "-0.001"),
    ({"batch_size": [32.0]}, {}, "32.0"),
    ({"n_epochs": [0]}, {}, "'n_epochs': value 0"),
    ({"gae_lambda": [1.5]}, {}, "1.5"),
    ({"clip_range": [0.0]}, {}, "'clip_range'"),
    ({"ent_coef": [0.01, 0.01]}, {}, "twice"),
    ({"vf_coef": ["0.5"]}, {}, "'0.5'"),
    ({"vf_coef": [0.5]}, {"c": -1.0}, "c=-1.0"),
    ({"vf_coef": [0.5]}, {"window": 0}, "window=0"),
    ({"vf_coef": [0.5]}, {"utility": "reward"}, "'reward'"),
])
def test_bad_search_spaces_are_refused_when_the_callback_is_built(space, options, named):
    with pytest.raises(ValueError, match="ULTHOCallback") as refused:
        ULTHOCallback(space, **options)
    assert named in str(refused.value)


@pytest.mark.parametrize("build, space, named", [
    (a2c, {"learning_rate": [1e-3], "batch_size": [8]}, "A2C has no 'batch_size'"),
    (a2c, {"n_epochs": [2]}, "A2C has no 'n_epochs'"),
    (a2c, {"clip_range": [0.1]}, "A2C has no 'clip_range'"),
    (ppo, {"batch_size": [16, 48]}, "batch_size 48 does not divide the rollout of n_steps * n_envs = 32 * 2 = 64"),
    (lambda: ppo(normalize_advantage=True), {"batch_size": [1, 64]}, "batch_size 1"),
    (lambda: DQN("MlpPolicy", cartpole(1), device="cpu"), {"learning_rate": [1e-3]}, "DQN is not an on-policy"),
])
def test_what_the_algorithm_cannot_take_is_refused_before_any_training(build, space, named):
    model = build()
    before = parameters(model)
    with pytest.raises(ValueError, match="ULTHOCallback") as refused:
        model.learn(4 * ROLLOUT, callback=ULTHOCallback(space))
    assert named in str(refused.value)
    assert model.num_timesteps == 0 and identical(parameters(model), before)


# ------------------------------------------------------------------------------------------- save and load
RESUME_SPACE = {"learning_rate": [1e-4, 1e-3], "batch_size": [16, 32], "gae_lambda": [0.8, 0.95],
                "clip_range": [0.1, 0.3]}


@pytest.mark.parametrize("options", [{"c": 1.0, "window": 3},
                                     {"window": 3, "strategy": "ts", "credit": "improvement", "scale": "running"},
                                     {"c": 1.0, "window": 3, "utility": "authors-return"}])
def test_save_and_load_continue_the_same_training_exactly(options, tmp_path):
    """A training saved after 4 rollouts and loaded (model and callback) goes on exactly as the uninterrupted
    one: same choices and credits, same final weights; with the paper's bandit and with a variant that draws
    from its own generator and needs the measured baseline of its pending choice. SB3 keeps neither the
    environments nor the global RNGs in model.save, so the test hands the loaded model the same environment
    object and restores the RNGs: what is left to differ is what the two files carry."""
    uninterrupted = ppo(n_epochs=2, seed=3)
    callback = ULTHOCallback(RESUME_SPACE, **options)
    uninterrupted.learn(4 * ROLLOUT, callback=callback)
    uninterrupted.learn(4 * ROLLOUT, callback=callback, reset_num_timesteps=False)

    first = ppo(n_epochs=2, seed=3)
    first_callback = ULTHOCallback(RESUME_SPACE, **options)
    first.learn(4 * ROLLOUT, callback=first_callback)
    rngs = torch.get_rng_state(), np.random.get_state(), random.getstate()
    env = first.get_env()
    path = tmp_path / "ppo_cartpole"
    first.save(path)
    assert first_callback.save(path) == str(tmp_path / "ppo_cartpole.ultho.json") == state_path(f"{path}.zip")
    authors = options.get("utility") == "authors-return"
    assert (first_callback.bandit.pending is None) == authors  # else the last train()'s choice awaits its credit
    saved = first_callback.bandit.state_dict()
    del first, first_callback

    resumed = PPO.load(path, env=env, force_reset=False, device="cpu")
    resumed_callback = ULTHOCallback.load(path)
    assert resumed_callback.bandit.state_dict() == saved
    torch.set_rng_state(rngs[0])
    np.random.set_state(rngs[1])
    random.setstate(rngs[2])
    resumed.learn(4 * ROLLOUT, callback=resumed_callback, reset_num_timesteps=False)

    assert resumed_callback.bandit.state_dict() == callback.bandit.state_dict()
    assert resumed_callback.bandit.num_selections == (7 if authors else 8)  # authors: the first withdrawn, once
    assert resumed_callback.chosen == callback.chosen and len(callback.chosen) >= (1 if authors else 3)
    assert resumed_callback.settings_in_force == callback.settings_in_force
    assert identical(parameters(resumed), parameters(uninterrupted))


def test_a_loaded_bandit_is_refused_by_a_model_at_another_step(tmp_path):
    model = ppo()
    callback = ULTHOCallback({"vf_coef": [0.5, 1.0]})
    model.learn(2 * ROLLOUT, callback=callback)
    callback.save(tmp_path / "run.zip")
    model.save(tmp_path / "run.zip")
    loaded = PPO.load(tmp_path / "run.zip", env=cartpole(), device="cpu")
    with pytest.raises(ValueError, match=r"saved at step 128 but the model is at step 0.*reset_num_timesteps=False"):
        loaded.learn(ROLLOUT, callback=ULTHOCallback.load(tmp_path / "run"))  # reset_num_timesteps forgotten
    assert loaded.num_timesteps == 0


def test_unreadable_or_foreign_state_files_are_refused(tmp_path):
    with pytest.raises(ValueError, match="cannot read .*missing.ultho.json"):
        ULTHOCallback.load(tmp_path / "missing")
    (tmp_path / "junk.ultho.json").write_text("not json")
    with pytest.raises(ValueError, match="cannot read .*junk.ultho.json"):
        ULTHOCallback.load(tmp_path / "junk")
    (tmp_path / "other.json").write_text('{"format": 1, "search_space": {}}')
    with pytest.raises(ValueError, match="other.json is not a saved ULTHOCallback"):
        ULTHOCallback.load(tmp_path / "other.json")
    callback = ULTHOCallback({"vf_coef": [0.5, 1.0]})
    state = callback.state_dict()
    state["bandit"]["num_selections"] = 5
    (tmp_path / "bad.json").write_text(json.dumps(state))
    with pytest.raises(ValueError, match="bad.json is malformed"):
        ULTHOCallback.load(tmp_path / "bad.json")


def test_bandit_options_are_passed_to_the_bandit_and_kept_by_save(tmp_path):
    """Extra keyword arguments reach ULTHO unchanged, and a saved callback brings them back."""
    options = {"c": 1.0, "window": 50, "strategy": "exp3", "credit": "improvement", "scale": "running", "seed": 7}
    callback = ULTHOCallback({"vf_coef": [0.5, 1.0]}, utility="return", **options)
    assert {k: callback.bandit.options()[k] for k in options} == options
    ppo().learn(3 * ROLLOUT, callback=callback)
    callback.save(tmp_path / "b.json")
    loaded = ULTHOCallback.load(tmp_path / "b.json")
    assert loaded.bandit.options() == callback.bandit.options() and loaded.utility == "return"
    assert loaded.bandit.state_dict() == callback.bandit.state_dict()
    with pytest.raises(TypeError, match="no_such_option"):
        ULTHOCallback({"vf_coef": [0.5]}, no_such_option=1)
    with pytest.raises(ValueError, match="ULTHOCallback: strategy='greedy'"):
        ULTHOCallback({"vf_coef": [0.5]}, strategy="greedy")


def test_save_every_checkpoints_model_and_bandit_together(tmp_path):
    """Every 2 rollouts and at the end: a model and a bandit of the same step, loadable together."""
    save_path = tmp_path / "ckpt" / "ppo"
    callback = ULTHOCallback({"vf_coef": [0.5, 1.0], "n_epochs": [1, 2]}, save_path=save_path, save_every=2)
    ppo().learn(5 * ROLLOUT, callback=callback)
    steps = [2 * ROLLOUT, 4 * ROLLOUT, 5 * ROLLOUT]
    assert sorted(os.listdir(tmp_path / "ckpt")) == sorted(
        os.path.basename(checkpoint_path(save_path, step)) + suffix for step in steps
        for suffix in (".zip", ".ultho.json"))
    for step in steps:
        model = PPO.load(checkpoint_path(save_path, step), device="cpu")
        loaded = ULTHOCallback.load(checkpoint_path(save_path, step))
        assert model.num_timesteps == step and loaded.bandit.num_selections == step // ROLLOUT
        assert {name: getattr(model, name) for name in loaded.chosen} == loaded.chosen
        assert (loaded.save_path, loaded.save_every) == (str(save_path), 2)
    assert latest_checkpoint(save_path) == checkpoint_path(save_path, 5 * ROLLOUT)
    assert latest_checkpoint(tmp_path / "elsewhere") is None
    with pytest.raises(ValueError, match="save_every needs a save_path"):
        ULTHOCallback({"vf_coef": [0.5]}, save_every=2)
    with pytest.raises(ValueError, match="save_every=-1"):
        ULTHOCallback({"vf_coef": [0.5]}, save_path=save_path, save_every=-1)


TRAIN_AND_CHECKPOINT = textwrap.dedent("""
    import sys
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from ultho_sb3 import ULTHOCallback
    model = PPO("MlpPolicy", make_vec_env("CartPole-v1", n_envs=2, seed=0), n_steps=32, batch_size=64, seed=0,
                device="cpu")
    model.learn(10_000 * 64, callback=ULTHOCallback({"vf_coef": [0.5, 1.0]}, save_path=sys.argv[1], save_every=1))
""")


def test_a_killed_training_resumes_from_its_latest_checkpoint(tmp_path):
    """SIGKILL at any moment leaves a complete model-and-bandit pair at most one interval old (here one
    rollout), and training goes on from it with the same bandit, still checkpointing."""
    save_path = str(tmp_path / "ppo")
    process = subprocess.Popen([sys.executable, "-c", TRAIN_AND_CHECKPOINT, save_path], cwd=REPO,
                               env={**os.environ, "PYTHONPATH": REPO}, stderr=subprocess.PIPE)
    deadline = time.time() + 300
    while not os.path.exists(checkpoint_path(save_path, 3 * ROLLOUT) + ".ultho.json") and time.time() < deadline:
        assert process.poll() is None, process.stderr.read().decode()
        time.sleep(0.01)
    process.send_signal(signal.SIGKILL)
    process.wait()
    path = latest_checkpoint(save_path)
    assert path is not None
    model = PPO.load(path, env=cartpole(), device="cpu")
    callback = ULTHOCallback.load(path)
    step = model.num_timesteps
    assert step >= 3 * ROLLOUT and callback.bandit.num_selections == step // ROLLOUT
    assert callback.bandit.pending is not None
    model.learn(2 * ROLLOUT, callback=callback, reset_num_timesteps=False)
    assert callback.bandit.num_selections == step // ROLLOUT + 2
    assert latest_checkpoint(save_path) == checkpoint_path(save_path, step + 2 * ROLLOUT)


# ------------------------------------------------------------------------------------------------ learning
def test_ppo_with_the_callback_learns_cartpole():
    """The README's example search space on CartPole-v1 with rl-zoo's PPO settings for it (8 environments, gamma 0.98,
    GAE lambda 0.8, minibatch 256; rollouts of 64 steps) for 32,768 steps: the greedy policy must average at
    least 195 over 20 fresh episodes (CartPole-v0's 'solved'). Seeds 0, 1 and 2 reached 500 by then."""
    model = PPO("MlpPolicy", make_vec_env("CartPole-v1", n_envs=8, seed=0), n_steps=64, batch_size=256,
                gae_lambda=0.8, gamma=0.98, ent_coef=0.0, clip_range=0.2, seed=0, device="cpu")
    callback = ULTHOCallback({"learning_rate": [1e-4, 3e-4, 1e-3], "n_epochs": [5, 10, 20]})
    model.learn(32_768, callback=callback)
    mean_return, _ = evaluate_policy(model, make_vec_env("CartPole-v1", n_envs=1, seed=1000), n_eval_episodes=20,
                                     deterministic=True)
    assert mean_return >= 195, (mean_return, callback.bandit.value_selections())

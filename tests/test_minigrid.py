"""ppo_ultho_minigrid.py, run for real on MiniGrid with tiny budgets."""

import math
import os
import shutil

import gymnasium as gym
import numpy as np
import pytest
import torch

from helpers import (
    assert_authors_credit_timing_and_exact_resume, assert_diverged_and_recorded,
    assert_existing_run_and_foreign_checkpoint_refused, assert_refused,
    assert_round_robin_rotation_in_force_and_exact_resume, evaluation_seeds, kill_after_first_checkpoint, run,
    run_bad_inputs, run_ok, scalars, summary,
)
from ultho_bandit import ULTHO

SCRIPT = "ppo_ultho_minigrid.py"
SPACE = {"learning_rate": [1e-3, 2.5e-3, 5e-3], "minibatch_size": [128, 256, 512], "vf_coef": [0.25, 0.5, 1.0]}
# 16 envs x 192 steps, two iterations: every DoorKey-6x6 episode (at most 360 steps) ends at least once.
TWO_ITERATIONS = ["--num-envs", "16", "--num-steps", "192", "--total-timesteps", "6144", "--eval-episodes", "3"]
CHARTS = ["charts/episodic_return", "charts/episodic_length", "charts/SPS", "charts/learning_rate",
          "losses/value_loss", "losses/policy_loss", "losses/entropy", "losses/approx_kl", "losses/old_approx_kl",
          "losses/clipfrac", "losses/explained_variance"]


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    run_ok(SCRIPT, *TWO_ITERATIONS, "--runs-dir", str(runs), "--run-name", "smoke")
    return str(runs / "smoke")


def test_smoke_run_writes_every_tensorboard_tag(smoke_run):
    series = scalars(smoke_run)
    expected = CHARTS + [f"hparams/{name}" for name in SPACE] + list(ULTHO(SPACE).scalars()) + ["ultho/credit"]
    missing = [tag for tag in expected if tag not in series]
    assert not missing, f"missing tags: {missing}"
    assert [step for step, _ in series["ultho/selected_cluster"]] == [3072, 6144]
    # Iteration 1 picks the first cluster's first value (every bound is 0); the tuned setting shows it.
    assert series["ultho/selected_cluster"][0][1] == 0.0
    assert series["hparams/learning_rate"][0][1] == pytest.approx(1e-3)
    assert series["charts/learning_rate"][0][1] == pytest.approx(1e-3)
    # Only iteration 2 has a credit: the one for iteration 1's choice.
    assert len(series["ultho/credit"]) == 1


def test_smoke_run_summary_fields(smoke_run):
    s = summary(smoke_run)
    assert s["global_step"] == 6144 and s["iterations"] == 2 and s["ultho"] is True
    assert s["env_id"] == "MiniGrid-DoorKey-6x6-v0" and s["settings"]["learning_rate"] == 1e-3
    assert s["wall_time_s"] > 0 and s["sps"] > 0
    assert 0 < s["final_score_episodes"] <= 100 and s["final_score"] is not None
    assert s["eval"]["episodes"] == 3 and len(s["eval"]["returns"]) == 3
    assert sum(s["bandit"]["selections"].values()) == 1  # the second selection is never credited
    assert s["bandit"]["coi"] in SPACE and s["bandit"]["noi"] in SPACE
    assert s["bandit"]["search_space"] == SPACE
    checkpoint = torch.load(os.path.join(smoke_run, "checkpoint.pt"), weights_only=False)
    assert checkpoint["iteration"] == 2 and checkpoint["global_step"] == 6144


def test_no_ultho_keeps_settings_fixed_and_logs_no_bandit_tags(tmp_path):
    run_ok(SCRIPT, *TWO_ITERATIONS, "--no-ultho", "--learning-rate", "0.002", "--runs-dir", str(tmp_path),
           "--run-name", "ppo")
    series = scalars(str(tmp_path / "ppo"))
    assert not [tag for tag in series if tag.startswith("ultho/")]
    assert [v for _, v in series["hparams/learning_rate"]] == pytest.approx([0.002, 0.002])
    assert [v for _, v in series["hparams/minibatch_size"]] == [256, 256]
    assert [v for _, v in series["hparams/vf_coef"]] == [0.5, 0.5]
    assert [v for _, v in series["charts/learning_rate"]] == pytest.approx([0.002, 0.002])
    s = summary(str(tmp_path / "ppo"))
    assert s["bandit"] is None
    assert s["settings_in_force"] == {"learning_rate": 0.002, "minibatch_size": 256, "vf_coef": 0.5}


def test_killed_and_resumed_run_equals_uninterrupted_run(tmp_path):
    # Empty-5x5 cuts episodes at 100 steps: with 50-step rollouts the first checkpoint (iteration 2) is written
    # right after episodes ended on the rollout's last step, while other environments are mid-episode.
    args = ["--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "8", "--num-steps", "50", "--total-timesteps",
            "4800", "--minibatch-size", "80", "--ultho-clusters", "learning_rate", "minibatch_size=40,80,200",
            "vf_coef", "--checkpoint-every", "2", "--eval-episodes", "2", "--quiet", "--runs-dir", str(tmp_path)]
    run_ok(SCRIPT, *args, "--run-name", "whole")
    kill_after_first_checkpoint(SCRIPT, str(tmp_path / "killed"), *args, "--run-name", "killed")
    checkpoint = torch.load(tmp_path / "killed" / "checkpoint.pt", weights_only=False)
    assert checkpoint["iteration"] < 12 and not (tmp_path / "killed" / "summary.json").exists()
    assert checkpoint["next_done"].any() and not checkpoint["next_done"].all()
    run_ok(SCRIPT, "--resume", str(tmp_path / "killed"), "--quiet")

    whole, resumed = summary(str(tmp_path / "whole")), summary(str(tmp_path / "killed"))
    for key in ("global_step", "bandit", "settings_in_force", "final_score", "eval"):
        assert whole[key] == resumed[key], key
    a, b = scalars(str(tmp_path / "whole")), scalars(str(tmp_path / "killed"))
    for tag in ("ultho/selected_cluster", "ultho/selected_value", "ultho/credit", "losses/value_loss",
                "hparams/learning_rate", "charts/learning_rate"):
        assert a[tag] == b[tag], tag
    assert len(a["ultho/selected_cluster"]) == 12


def test_variant_run_logs_its_own_quantities_and_resumes_exactly(tmp_path):
    """Thompson sampling on improvement credits in running-scale units: killed and resumed, the same run (the
    generator's state is in the checkpoint); each credit is the change of the measured value."""
    args = ["--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "8", "--num-steps", "64", "--total-timesteps",
            "6144", "--minibatch-size", "128", "--ultho-strategy", "ts", "--ultho-credit", "improvement",
            "--ultho-scale", "running", "--checkpoint-every", "2", "--eval-episodes", "0", "--quiet",
            "--runs-dir", str(tmp_path)]
    run_ok(SCRIPT, *args, "--run-name", "whole")
    kill_after_first_checkpoint(SCRIPT, str(tmp_path / "killed"), *args, "--run-name", "killed")
    assert not (tmp_path / "killed" / "summary.json").exists()
    run_ok(SCRIPT, "--resume", str(tmp_path / "killed"), "--quiet")
    whole, resumed = summary(str(tmp_path / "whole")), summary(str(tmp_path / "killed"))
    assert whole["bandit"] == resumed["bandit"]
    assert (whole["bandit"]["strategy"], whole["bandit"]["credit"], whole["bandit"]["scale"]) == \
        ("ts", "improvement", "running")
    a, b = scalars(str(tmp_path / "whole")), scalars(str(tmp_path / "killed"))
    for tag in ("ultho/selected_cluster", "ultho/selected_value", "ultho/last_credit", "ultho/credit_scale",
                "ultho/ts_mean/learning_rate", "ultho/ts_std/vf_coef/0.5", "losses/value_loss"):
        np.testing.assert_array_equal(np.array(a[tag]), np.array(b[tag]), err_msg=tag)  # nan before any credit
    assert "ultho/ucb/learning_rate" not in a
    measured = [v for _, v in a["ultho/credit"]]  # the value measured at iterations 2..12
    improvements = [v for _, v in a["ultho/last_credit"]][2:]  # credited at iterations 3..12 (1: none, 2: from V-bar 1)
    assert improvements == pytest.approx([now - before for before, now in zip(measured, measured[1:])], abs=1e-6)
    assert len(set(v for _, v in a["ultho/selected_cluster"])) > 1


def test_exp3_run_logs_probabilities_that_sum_to_one(tmp_path):
    run_ok(SCRIPT, "--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "4", "--num-steps", "64", "--total-timesteps",
           "1280", "--minibatch-size", "64", "--ultho-clusters", "minibatch_size=64,128", "vf_coef",
           "--ultho-strategy", "exp3", "--eval-episodes", "0", "--runs-dir", str(tmp_path), "--run-name", "e")
    series = scalars(str(tmp_path / "e"))
    for k in range(5):
        clusters = series["ultho/probability/minibatch_size"][k][1] + series["ultho/probability/vf_coef"][k][1]
        values = sum(series[f"ultho/probability/vf_coef/{v}"][k][1] for v in ("0.25", "0.5", "1.0"))
        assert clusters == pytest.approx(1.0, abs=1e-6) and values == pytest.approx(1.0, abs=1e-6)
    assert summary(str(tmp_path / "e"))["bandit"]["exp3_eta"] == 0.5


# 8 envs x 64 steps on Empty-5x5, plain PPO: 6 iterations to the first run's end, 12 to the whole run's.
INIT_FROM = ["--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "8", "--num-steps", "64", "--minibatch-size", "128",
             "--no-ultho", "--eval-episodes", "2", "--quiet"]


@pytest.fixture(scope="module")
def first_half(tmp_path_factory):
    """A run to step 3072 and the uninterrupted run to 6144 with the same settings and seed."""
    runs = tmp_path_factory.mktemp("init")
    run_ok(SCRIPT, *INIT_FROM, "--total-timesteps", "3072", "--runs-dir", str(runs), "--run-name", "first")
    run_ok(SCRIPT, *INIT_FROM, "--total-timesteps", "6144", "--runs-dir", str(runs), "--run-name", "whole")
    return runs


def test_init_from_in_place_with_the_same_settings_and_seed_equals_the_uninterrupted_run(first_half, tmp_path):
    """Network, optimizer, environments, counters and random generators all come from the checkpoint."""
    shutil.copytree(first_half / "first", tmp_path / "first")
    run_ok(SCRIPT, *INIT_FROM, "--total-timesteps", "6144", "--init-from", str(tmp_path / "first"),
           "--runs-dir", str(tmp_path), "--run-name", "first")
    whole, continued = summary(str(first_half / "whole")), summary(str(tmp_path / "first"))
    for key in ("global_step", "iterations", "final_score", "final_score_episodes", "eval", "settings_in_force"):
        assert whole[key] == continued[key], key
    a, b = scalars(str(first_half / "whole")), scalars(str(tmp_path / "first"))
    for tag in ("losses/value_loss", "losses/policy_loss", "charts/episodic_return", "hparams/learning_rate"):
        assert a[tag] == b[tag], tag  # both halves, read from the directory's two event files
    a, b = (torch.load(d / "checkpoint.pt", weights_only=False) for d in (first_half / "whole", tmp_path / "first"))
    assert all(torch.equal(a["agent"][k], b["agent"][k]) for k in a["agent"])


def test_init_from_puts_the_new_settings_in_force_everywhere(first_half, tmp_path):
    """The optimizer's restored state must not bring back the source's learning rate."""
    source = torch.load(first_half / "first" / "checkpoint.pt", weights_only=False)
    assert source["optimizer"]["param_groups"][0]["lr"] == 1e-3
    run_ok(SCRIPT, *INIT_FROM, "--total-timesteps", "6144", "--init-from", str(first_half / "first"),
           "--learning-rate", "0.005", "--minibatch-size", "256", "--vf-coef", "1.0", "--seed", "7",
           "--runs-dir", str(tmp_path), "--run-name", "new")
    series = scalars(str(tmp_path / "new"))
    # The counters continue the source's: iterations 7-12, steps 3584-6144.
    assert [step for step, _ in series["hparams/learning_rate"]] == list(range(3584, 6145, 512))
    assert [v for _, v in series["hparams/learning_rate"]] == pytest.approx([0.005] * 6)
    assert [v for _, v in series["charts/learning_rate"]] == pytest.approx([0.005] * 6)  # the optimizer's own
    assert {v for _, v in series["hparams/minibatch_size"]} == {256.0}
    assert {v for _, v in series["hparams/vf_coef"]} == {1.0}
    s = summary(str(tmp_path / "new"))
    assert s["settings_in_force"] == {"learning_rate": 0.005, "minibatch_size": 256, "vf_coef": 1.0}
    assert s["settings"]["init_from"] == str(first_half / "first") and s["global_step"] == 6144
    checkpoint = torch.load(tmp_path / "new" / "checkpoint.pt", weights_only=False)
    assert checkpoint["optimizer"]["param_groups"][0]["lr"] == 0.005
    assert checkpoint["config"]["learning_rate"] == 0.005 and checkpoint["iteration"] == 12
    # The source's optimizer state came along: Adam's step count goes on from the source's.
    steps_per_iteration = 4 * 512 // 256
    assert (checkpoint["optimizer"]["state"][0]["step"]
            == source["optimizer"]["state"][0]["step"] + 6 * steps_per_iteration)


def test_init_from_refuses_another_rollout_or_an_exhausted_budget(first_half, tmp_path):
    first = str(first_half / "first")
    for args, named in ((["--num-envs", "4", "--total-timesteps", "6144"],
                         "its num_envs is 8, this run's --num-envs 4"),
                        (["--env-id", "MiniGrid-Empty-6x6-v0", "--total-timesteps", "6144"], "its env_id is"),
                        (["--total-timesteps", "3072"], "is already at step 3072")):
        result = run(SCRIPT, *INIT_FROM, "--init-from", first, *args, "--runs-dir", str(tmp_path / "r"))
        assert_refused(SCRIPT, str(tmp_path / "r"), result, named)
    # Only a run of this script may be continued in its own directory.
    (tmp_path / "taken").mkdir()
    result = run(SCRIPT, *INIT_FROM, "--init-from", first, "--total-timesteps", "6144", "--runs-dir", str(tmp_path),
                 "--run-name", "taken")
    assert result.returncode == 2 and "run directory" in result.stderr and "already exists" in result.stderr
    assert os.listdir(tmp_path / "taken") == []


def test_non_finite_loss_stops_the_run_and_its_summary_records_it(tmp_path):
    # Iteration 1 takes lr=1e-3 (every bound is 0). Iteration 2 explores the untried 1e38, whose bonus
    # c*sqrt(ln 2 / 1) exceeds the tried arm's by 5*(0.83-0.59) = 1.2 while |credit| < 1 on Empty-5x5.
    result = run(SCRIPT, "--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "4", "--num-steps", "64",
                 "--total-timesteps", "2048", "--minibatch-size", "64", "--ultho-clusters", "learning_rate=0.001,1e38",
                 "--checkpoint-every", "1", "--runs-dir", str(tmp_path), "--run-name", "nan")
    recorded = assert_diverged_and_recorded(result, tmp_path / "nan", 2, "learning_rate=1e+38", "agent")
    assert recorded["diverged"]["what"] == "loss" and recorded["settings_in_force"]["learning_rate"] == 1e38


BAD_INPUTS = [
    (["--env-id", "MiniGrid-NoSuchThing-v0"], "MiniGrid-NoSuchThing-v0"),
    (["--env-id", "CartPole-v1"], "CartPole-v1"),
    (["--num-envs", "0"], "--num-envs must be positive, got 0"),
    (["--num-steps", "-3"], "--num-steps must be positive, got -3"),
    (["--torch-threads", "-1"], "--torch-threads must be >= 0 (0: one per core), got -1"),
    (["--num-steps", "abc"], "abc"),
    (["--minibatch-size", "300"], "300 does not divide"),
    (["--ultho-clusters", "momentum"], "momentum"),
    (["--ultho-clusters", "minibatch_size=100,256"], "100 does not divide"),
    (["--ultho-clusters", "learning_rate=0.001,-1"], "-1"),
    (["--ultho-clusters", "vf_coef=0.5,"], "vf_coef=0.5,"),
    (["--ultho-c", "-1"], "--ultho-c must be a finite number >= 0, got -1.0"),
    (["--ultho-window", "0"], "--ultho-window must be >= 1, got 0"),
    (["--ultho-strategy", "greedy"], "greedy"),
    (["--ultho-credit", "delta"], "delta"),
    (["--ultho-exp3-eta", "0"], "--ultho-exp3-eta must be a finite number > 0, got 0.0"),
    (["--ultho-utility", "reward"], "reward"),
    (["--total-timesteps", "100"], "--total-timesteps 100"),
    (["--learning-rate", "-0.1"], "-0.1"),
    (["--gamma", "1.5"], "--gamma must be in (0, 1], got 1.5"),
    (["--resume", "/no/such/run"], "/no/such/run"),
    (["--init-from", "/no/such/run"], "--init-from /no/such/run: no checkpoint.pt there"),
    (["--resume", "/no/such/run", "--init-from", "/no/such/run"], "--resume and --init-from exclude each other"),
    (["--bogus-flag", "1"], "--bogus-flag"),
    (["--run-name", "a/b"], "'a/b'"),
]


@pytest.fixture(scope="module")
def bad_input_results(tmp_path_factory):
    return run_bad_inputs(SCRIPT, [args for args, _ in BAD_INPUTS], tmp_path_factory.mktemp("bad"))


@pytest.mark.parametrize("case", range(len(BAD_INPUTS)), ids=[" ".join(a) for a, _ in BAD_INPUTS])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(bad_input_results, case):
    assert_refused(SCRIPT, *bad_input_results[case], BAD_INPUTS[case][1])


def test_existing_run_directory_and_foreign_checkpoint_are_refused(tmp_path):
    assert_existing_run_and_foreign_checkpoint_refused(SCRIPT, tmp_path)


def test_help_lists_every_flag():
    result = run(SCRIPT, "--help")
    assert result.returncode == 0
    for flag in ("--env-id", "--total-timesteps", "--minibatch-size", "--ultho-clusters", "--no-ultho",
                 "--ultho-utility", "--resume", "--checkpoint-every", "--eval-episodes", "--quiet"):
        assert flag in result.stdout


@pytest.mark.parametrize("utility", ["return", "value-after"])
def test_other_utility_signals_credit_every_choice(tmp_path, utility):
    run_ok(SCRIPT, "--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "4", "--num-steps", "64", "--total-timesteps",
           "768", "--minibatch-size", "64", "--ultho-clusters", "minibatch_size=64,128", "vf_coef",
           "--ultho-utility", utility, "--eval-episodes", "0", "--runs-dir", str(tmp_path), "--run-name", "u")
    s = summary(str(tmp_path / "u"))
    credited = sum(s["bandit"]["selections"].values())
    # value-after credits within the iteration (all three), return credits at the next one (two of three).
    assert credited == (3 if utility == "value-after" else 2)
    credits = [v for _, v in scalars(str(tmp_path / "u"))["ultho/credit"]]
    assert len(credits) == credited and all(math.isfinite(c) for c in credits)


def test_ppo_learns_empty_5x5(tmp_path):
    # Fixed PPO (the script's defaults, lr 1e-3): 24 iterations take the return past 0.8 by step 20K and hold it
    # near 0.955 on seeds 1-4. With the bandit on, whether the run survives is a matter of floating-point luck:
    # once the policy is near-deterministic an iteration at ULTHO's lr 5e-3 can jump it to a non-solving
    # deterministic policy that never recovers, and seed 1 did so on one x86 CPU and not on another (final
    # score 0.19 against 0.95). A learning test must not depend on the CPU, so the bandit stays off here; the
    # bandit's own behaviour is tested by hand-computed sequences.
    run_ok(SCRIPT, "--env-id", "MiniGrid-Empty-5x5-v0", "--total-timesteps", "49152", "--eval-episodes", "20",
           "--no-ultho", "--quiet", "--runs-dir", str(tmp_path), "--run-name", "learn")
    s = summary(str(tmp_path / "learn"))
    # A random policy scores about 0.1 here; the optimal return is about 0.96.
    assert s["final_score"] >= 0.8, s["final_score"]
    assert s["eval"]["mean_return"] >= 0.8, s["eval"]


@pytest.mark.parametrize("env_id", ["MiniGrid-LavaGapS7-v0", "MiniGrid-Empty-16x16-v0", "MiniGrid-KeyCorridorS3R1-v0"])
def test_other_minigrid_environments_run(tmp_path, env_id):
    run_ok(SCRIPT, "--env-id", env_id, "--num-envs", "4", "--num-steps", "128", "--total-timesteps", "512",
           "--eval-episodes", "1", "--quiet", "--runs-dir", str(tmp_path), "--run-name", "other")
    s = summary(str(tmp_path / "other"))
    assert s["env_id"] == env_id and s["global_step"] == 512 and s["eval"]["episodes"] == 1


# Many layouts and objects: doors (open, closed, locked), keys, balls and boxes to carry, lava, moving
# obstacles, rooms; occlusion on (DoorKey, KeyCorridor, ...) and off (Empty, Fetch, Dynamic-Obstacles).
EQUIVALENCE_ENVS = ["MiniGrid-DoorKey-6x6-v0", "MiniGrid-LavaGapS7-v0", "MiniGrid-Empty-16x16-v0",
                    "MiniGrid-KeyCorridorS3R1-v0", "MiniGrid-MultiRoom-N2-S4-v0", "MiniGrid-Dynamic-Obstacles-6x6-v0",
                    "MiniGrid-Fetch-5x5-N2-v0", "MiniGrid-ObstructedMaze-1Dlhb-v0", "MiniGrid-BlockedUnlockPickup-v0",
                    "MiniGrid-MemoryS7-v0"]


@pytest.mark.parametrize("env_id", EQUIVALENCE_ENVS)
def test_fast_gen_obs_equals_minigrids_own(env_id):
    from ppo_ultho_minigrid import MINIGRID_GEN_OBS, fast_gen_obs
    env = gym.make(env_id)
    env.reset(seed=0)
    grid_env = env.unwrapped
    rng = np.random.default_rng(0)
    directions, carrying = set(), 0
    for step in range(1500):
        expected, fast = MINIGRID_GEN_OBS(grid_env), fast_gen_obs(grid_env)
        assert fast["image"].dtype == np.uint8 and fast["image"].shape == expected["image"].shape
        assert np.array_equal(fast["image"], expected["image"]), (env_id, step)
        assert (fast["direction"], fast["mission"]) == (expected["direction"], expected["mission"])
        directions.add(grid_env.agent_dir)
        carrying += grid_env.carrying is not None
        # Random actions, with "pick up" and "toggle" (doors) twice as likely, to reach more object states.
        action = rng.choice([0, 1, 2, 3, 3, 4, 5, 5, 6])
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset(seed=int(rng.integers(1 << 30)))
    assert directions == {0, 1, 2, 3}
    if env_id in ("MiniGrid-DoorKey-6x6-v0", "MiniGrid-KeyCorridorS3R1-v0", "MiniGrid-BlockedUnlockPickup-v0"):
        assert carrying > 0, "the walk never picked anything up: the carried-object case went untested"


def test_fast_obs_run_equals_minigrid_obs_run(tmp_path):
    for flag, name in (("--fast-obs", "fast"), ("--no-fast-obs", "minigrid")):
        run_ok(SCRIPT, *TWO_ITERATIONS, flag, "--quiet", "--runs-dir", str(tmp_path), "--run-name", name)
    fast, slow = summary(str(tmp_path / "fast")), summary(str(tmp_path / "minigrid"))
    assert fast["settings"]["fast_obs"] is True and slow["settings"]["fast_obs"] is False
    for key in ("global_step", "bandit", "final_score", "eval"):
        assert fast[key] == slow[key], key
    a, b = (torch.load(tmp_path / name / "checkpoint.pt", weights_only=False)["agent"] for name in ("fast", "minigrid"))
    assert all(torch.equal(a[k], b[k]) for k in a)


# Six iterations, a checkpoint every two: the authors' credit and the round robin, each killed and resumed.
SIX_ITERATIONS = ["--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "8", "--num-steps", "64",
                  "--total-timesteps", "3072", "--minibatch-size", "128", "--checkpoint-every", "2"]


def test_authors_credit_goes_to_the_choice_just_made_and_resumes_exactly(tmp_path):
    args = [*SIX_ITERATIONS, "--runs-dir", str(tmp_path)]
    assert_authors_credit_timing_and_exact_resume(SCRIPT, tmp_path, args)


def test_round_robin_takes_the_values_in_turn_and_resumes_exactly(tmp_path):
    args = [*SIX_ITERATIONS, "--runs-dir", str(tmp_path)]
    assert_round_robin_rotation_in_force_and_exact_resume(SCRIPT, tmp_path, args)


def test_evaluation_seeds_are_shared_by_no_neighbouring_run_and_no_training_episode(monkeypatch):
    # The evaluation played with a fresh network for run seeds 1 and 2, its resets recorded. Consecutive seeds
    # (seed + 1,000,000 + k) gave the two runs 9 of the same 10 episodes.
    import ppo_ultho_minigrid as script

    seeds = {}
    for seed in (1, 2):
        args = script.parse_args(["--env-id", "MiniGrid-Empty-5x5-v0", "--seed", str(seed), "--eval-episodes", "10"])
        envs = script.make_envs(args.env_id, 1)
        agent = script.Agent(int(np.prod(envs.single_observation_space.shape)), envs.single_action_space.n)
        envs.close()
        seeds[seed] = evaluation_seeds(script, monkeypatch, agent, args, torch.device("cpu"))
        assert len(set(seeds[seed])) == 10
    assert not set(seeds[1]) & set(seeds[2])
    # Training seeds its environments seed + k (k < --num-envs) once, at its start; autoreset draws the rest.
    training = {seed + k for seed in (1, 2) for k in range(script.Args.num_envs)}
    assert not (set(seeds[1]) | set(seeds[2])) & training

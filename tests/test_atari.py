"""ppo_ultho_atari.py, run for real on ALE games with tiny budgets (the Nature CNN is the cost on 2 cores)."""

import math
import os

import numpy as np
import pytest
import torch

from helpers import (
    assert_authors_credit_timing_and_exact_resume, assert_bf16_resume_equals_uninterrupted,
    assert_diverged_and_recorded, assert_existing_run_and_foreign_checkpoint_refused, assert_refused,
    assert_round_robin_rotation_in_force_and_exact_resume, bf16_against_float32, evaluation_seeds,
    kill_after_first_checkpoint, real_rollout, run, run_bad_inputs, run_concurrently, run_ok, scalars, summary,
)
from ultho_bandit import ULTHO

SCRIPT = "ppo_ultho_atari.py"
SPACE = {"minibatch_size": [128, 256, 512], "vf_coef": [0.25, 0.5, 1.0], "ent_coef": [0.01, 0.05, 0.1]}
# Qbert, because its games are short under a near-random policy (about 300-370 steps): 4 envs x 128 steps,
# four iterations, so games end and a score exists; the paper's search space divides the rollout of 512.
FOUR_ITERATIONS = ["--env-id", "Qbert", "--num-envs", "4", "--num-steps", "128", "--total-timesteps", "2048",
                   "--eval-episodes", "2"]
CHARTS = ["charts/episodic_return", "charts/episodic_length", "charts/SPS", "charts/learning_rate",
          "losses/value_loss", "losses/policy_loss", "losses/entropy", "losses/approx_kl", "losses/old_approx_kl",
          "losses/clipfrac", "losses/explained_variance"]
QBERT_RANDOM, QBERT_HUMAN = 163.9, 13455.0


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    runs = tmp_path_factory.mktemp("runs")
    run_ok(SCRIPT, *FOUR_ITERATIONS, "--runs-dir", str(runs), "--run-name", "smoke")
    return str(runs / "smoke")


def test_smoke_run_writes_every_tensorboard_tag(smoke_run):
    series = scalars(smoke_run)
    expected = CHARTS + [f"hparams/{name}" for name in SPACE] + list(ULTHO(SPACE).scalars()) + ["ultho/credit"]
    missing = [tag for tag in expected if tag not in series]
    assert not missing, f"missing tags: {missing}"
    assert [step for step, _ in series["ultho/selected_cluster"]] == [512, 1024, 1536, 2048]
    # Iteration 1 picks the first cluster's first value (every bound is 0); the tuned setting shows it.
    assert series["ultho/selected_cluster"][0][1] == 0.0
    assert series["hparams/minibatch_size"][0][1] == 128
    assert series["charts/learning_rate"][0][1] == pytest.approx(2.5e-4)
    assert len(series["ultho/credit"]) == 3  # every iteration but the first credits the one before it


def test_smoke_run_records_unclipped_game_scores(smoke_run):
    # Qbert scores 25 points a cube: unclipped game scores are multiples of 25, clipped or normalized ones are not.
    s = summary(smoke_run)
    assert s["eval"]["returns"] and all(r % 25 == 0 for r in s["eval"]["returns"]) and max(s["eval"]["returns"]) > 0
    total = s["final_score"] * s["final_score_episodes"]
    assert total > 0 and round(total) % 25 == 0 and total == pytest.approx(round(total)), s
    assert len(scalars(smoke_run)["charts/episodic_return"]) >= 1
    # Whole games (all lives), not single lives: a game of Qbert under a near-random policy lasts 200+ steps.
    assert s["final_episode_length"] > 150, s["final_episode_length"]


def test_smoke_run_summary_fields(smoke_run):
    s = summary(smoke_run)
    assert s["script"] == "ppo_ultho_atari" and s["env_id"] == "Qbert"
    assert s["precision"] == s["settings"]["precision"] == "float32"
    assert s["global_step"] == 2048 and s["iterations"] == 4 and s["ultho"] is True
    assert s["settings"]["learning_rate"] == 2.5e-4 and s["settings"]["num_envs"] == 4
    assert s["wall_time_s"] > 0 and s["sps"] > 0 and 0 <= s["ultho_share"] < 1
    assert s["rollout_seconds"] > 0 and s["update_seconds"] > 0
    assert s["rollout_seconds"] + s["update_seconds"] < s["wall_time_s"]
    assert s["peak_rss_mb"] > 0 and (s["peak_cuda_mb"] is None) == (s["device"] == "cpu")
    assert 0 < s["final_score_episodes"] <= 100
    assert s["human_normalized_score"] == pytest.approx((s["final_score"] - QBERT_RANDOM)
                                                        / (QBERT_HUMAN - QBERT_RANDOM))
    assert s["eval"]["episodes"] == 2 and len(s["eval"]["returns"]) == 2
    assert sum(s["bandit"]["selections"].values()) == 3  # the last selection is never credited
    assert s["bandit"]["coi"] in SPACE and s["bandit"]["noi"] in SPACE
    assert s["bandit"]["search_space"] == SPACE
    assert set(s["settings_in_force"]) == set(SPACE)
    checkpoint = torch.load(os.path.join(smoke_run, "checkpoint.pt"), weights_only=False)
    assert checkpoint["iteration"] == 4 and checkpoint["global_step"] == 2048
    assert checkpoint["return_rms"]["count"] > 2048  # the reward normalization's statistics are saved


def test_no_ultho_keeps_settings_fixed_and_logs_no_bandit_tags(tmp_path):
    run_ok(SCRIPT, "--env-id", "Qbert", "--num-envs", "4", "--num-steps", "64", "--total-timesteps", "512",
           "--minibatch-size", "128", "--ent-coef", "0.05", "--no-ultho", "--eval-episodes", "0",
           "--runs-dir", str(tmp_path), "--run-name", "ppo")
    series = scalars(str(tmp_path / "ppo"))
    assert not [tag for tag in series if tag.startswith("ultho/")]
    assert [v for _, v in series["hparams/minibatch_size"]] == [128, 128]
    assert [v for _, v in series["hparams/ent_coef"]] == pytest.approx([0.05, 0.05])
    assert [v for _, v in series["hparams/vf_coef"]] == [0.5, 0.5]
    s = summary(str(tmp_path / "ppo"))
    assert s["bandit"] is None and s["settings_in_force"] == {"minibatch_size": 128, "vf_coef": 0.5, "ent_coef": 0.05}


def test_killed_and_resumed_run_equals_uninterrupted_run(tmp_path):
    # Breakout's games are short, so games end before the checkpoint and others are in progress at it: the
    # resumed run must replay those (the native environment's state cannot be saved) and go on identically.
    args = ["--env-id", "Breakout", "--num-envs", "4", "--num-steps", "64", "--total-timesteps", "1536",
            "--minibatch-size", "64", "--ultho-clusters", "minibatch_size=32,64,128", "vf_coef", "ent_coef",
            "--checkpoint-every", "3", "--eval-episodes", "2", "--quiet", "--runs-dir", str(tmp_path)]
    run_ok(SCRIPT, *args, "--run-name", "whole")
    kill_after_first_checkpoint(SCRIPT, str(tmp_path / "killed"), *args, "--run-name", "killed")
    checkpoint = torch.load(tmp_path / "killed" / "checkpoint.pt", weights_only=False)
    assert checkpoint["iteration"] < 6 and not (tmp_path / "killed" / "summary.json").exists()
    assert checkpoint["games"]["started"].sum() >= 1, "no game ended before the checkpoint"
    assert any(len(h) > 0 for h in checkpoint["games"]["actions"]), "no game in progress at the checkpoint"
    assert checkpoint["bandit"]["pending"] is not None  # the choice not yet credited is saved
    run_ok(SCRIPT, "--resume", str(tmp_path / "killed"), "--quiet")

    whole, resumed = summary(str(tmp_path / "whole")), summary(str(tmp_path / "killed"))
    for key in ("global_step", "bandit", "settings_in_force", "final_score", "final_score_episodes", "eval"):
        assert whole[key] == resumed[key], key
    a, b = scalars(str(tmp_path / "whole")), scalars(str(tmp_path / "killed"))
    for tag in ("ultho/selected_cluster", "ultho/selected_value", "ultho/credit", "losses/value_loss",
                "losses/policy_loss", "charts/episodic_return", "hparams/minibatch_size", "hparams/ent_coef"):
        assert a[tag] == b[tag], tag
    assert len(a["ultho/selected_cluster"]) == 6


def test_checkpoint_right_after_a_game_ended_on_a_rollouts_last_step_resumes_exactly(tmp_path):
    # Without no-op starts a game of Boxing lasts exactly 1785 steps (the clock runs out): with 255-step rollouts
    # the checkpoint at iteration 7 is written just after every game ended, so the next game has no actions yet.
    args = ["--env-id", "Boxing", "--noop-max", "0", "--num-envs", "1", "--num-steps", "255", "--total-timesteps",
            "2040", "--minibatch-size", "255", "--update-epochs", "1", "--ultho-clusters", "minibatch_size=85,255",
            "vf_coef", "--checkpoint-every", "7", "--eval-episodes", "0", "--quiet", "--runs-dir", str(tmp_path)]
    run_ok(SCRIPT, *args, "--run-name", "whole")
    kill_after_first_checkpoint(SCRIPT, str(tmp_path / "killed"), *args, "--run-name", "killed")
    checkpoint = torch.load(tmp_path / "killed" / "checkpoint.pt", weights_only=False)
    assert checkpoint["iteration"] == 7 and checkpoint["global_step"] == 1785
    assert list(checkpoint["games"]["started"]) == [1] and len(checkpoint["games"]["actions"][0]) == 0
    run_ok(SCRIPT, "--resume", str(tmp_path / "killed"), "--quiet")

    whole, resumed = summary(str(tmp_path / "whole")), summary(str(tmp_path / "killed"))
    for key in ("global_step", "bandit", "settings_in_force", "final_score", "final_score_episodes"):
        assert whole[key] == resumed[key], key
    final_whole = torch.load(tmp_path / "whole" / "checkpoint.pt", weights_only=False)
    final_resumed = torch.load(tmp_path / "killed" / "checkpoint.pt", weights_only=False)
    for name, tensor in final_whole["agent"].items():
        assert torch.equal(tensor, final_resumed["agent"][name]), name


def test_bf16_run_killed_and_resumed_continues_in_bf16_and_equals_uninterrupted_run(tmp_path):
    # The resume command leaves --precision out: bf16 must come back from the checkpoint, and bf16's kernels on
    # the CPU must be as repeatable as float32's. Plain PPO, so that the two continuations differ only in precision.
    args = ["--env-id", "Breakout", "--num-envs", "2", "--num-steps", "64", "--total-timesteps", "512",
            "--minibatch-size", "64", "--no-ultho", "--checkpoint-every", "2", "--eval-episodes", "1", "--quiet",
            "--runs-dir", str(tmp_path)]
    assert_bf16_resume_equals_uninterrupted(SCRIPT, tmp_path, args, "final_score")


@pytest.mark.parametrize("seed", [1, 2])
def test_bf16_gradient_agrees_with_float32_on_a_real_rollout(seed):
    # A paper-size minibatch (256) of Breakout played by the freshly initialized network, the PPO loss computed
    # by the script's own ppo_loss under both precisions with the same weights. Measured on seeds 1-8 (docs/
    # precision.md): cosine 0.9991-0.9999, relative norm difference 0.020-0.049, ratio deviation 1.6e-5 to
    # 2.6e-5; a log-softmax left in bf16 moves the ratio by 5e-3, which the last bound catches.
    import ppo_ultho_atari as script

    torch.manual_seed(seed)
    args = script.parse_args(["--env-id", "Breakout", "--num-envs", "8", "--num-steps", "32", "--seed", str(seed)])
    envs = script.make_envs(args, args.num_envs)
    obs, _ = envs.reset(seed=script.game_seeds(seed, np.arange(args.num_envs), np.zeros(args.num_envs, dtype=int)))
    agent = script.Agent(envs.single_action_space.n, "float32")
    batch = real_rollout(script, agent, envs, obs, args)
    envs.close()
    agreement = bf16_against_float32(script, agent, args, batch)
    assert agreement["cosine"] > 0.99, agreement
    assert 0 < agreement["relative_norm_difference"] < 0.15, agreement  # > 0: bf16 was in effect
    assert 0 < agreement["ratio_deviation"] < 1e-3, agreement


def test_evaluation_seeds_are_shared_by_no_neighbouring_run_and_no_training_game(monkeypatch):
    # The evaluation played with a fresh network for run seeds 1 and 2, its resets recorded. Consecutive seeds
    # (seed + 1,000,000 + k) gave the two runs 9 of the same 10 games.
    import ppo_ultho_atari as script

    seeds = {}
    for seed in (1, 2):
        torch.manual_seed(seed)
        args = script.parse_args(["--env-id", "Qbert", "--seed", str(seed), "--eval-episodes", "10"])
        envs = script.make_envs(args, 1)
        agent = script.Agent(envs.single_action_space.n, "float32")
        envs.close()
        seeds[seed] = evaluation_seeds(script, monkeypatch, agent, args, torch.device("cpu"))
        assert len(set(seeds[seed])) == 10
    assert not set(seeds[1]) & set(seeds[2])
    # Every training game has a seed of its own, fixed by (run seed, environment, game): none of the first 1,000
    # games of 8 environments in either run is an evaluation game.
    environments, games = np.meshgrid(np.arange(8), np.arange(1000))
    training = {int(s) for seed in (1, 2) for s in script.game_seeds(seed, environments.ravel(), games.ravel())}
    assert not (set(seeds[1]) | set(seeds[2])) & training


def test_non_finite_loss_stops_the_run_and_its_summary_records_it(tmp_path):
    # Iteration 1 takes the first value (every bound is 0); with c = 1000 iteration 2 must explore the untried 1e38.
    result = run(SCRIPT, "--env-id", "Qbert", "--num-envs", "2", "--num-steps", "32", "--total-timesteps", "128",
                 "--minibatch-size", "32", "--ultho-clusters", "learning_rate=0.00025,1e38", "--ultho-c", "1000",
                 "--checkpoint-every", "1", "--runs-dir", str(tmp_path), "--run-name", "nan")
    recorded = assert_diverged_and_recorded(result, tmp_path / "nan", 2, "learning_rate=1e+38", "agent")
    assert recorded["diverged"]["what"] == "loss" and recorded["settings_in_force"]["learning_rate"] == 1e38


def noops_after_a_lost_life(game: str, fire_first: bool, steps: int = 300) -> tuple[int, int]:
    """The script's own environment (one game, seeded as training seeds it) played at random until it loses a
    life, then given only NOOPs (after one FIRE with ``fire_first``): (lives lost during the NOOPs, distinct
    newest frames among them)."""
    import ppo_ultho_atari as script

    envs = script.make_envs(script.parse_args(["--env-id", game, "--num-envs", "1"]), 1)
    rng = np.random.default_rng(1)
    _, info = envs.reset(seed=script.game_seeds(1, np.arange(1), np.zeros(1, dtype=int)))
    lives = info["lives"][0]
    while info["lives"][0] == lives:
        _, _, terminated, truncated, info = envs.step(rng.integers(envs.single_action_space.n, size=1))
        assert not (terminated | truncated).any(), f"{game}: the game ended before it lost a life"
    lives = info["lives"][0]
    if fire_first:
        envs.step(np.array([1]))
    lost, frames = 0, set()
    for _ in range(steps):
        obs, _, terminated, truncated, info = envs.step(np.array([0]))
        if (terminated | truncated).any():
            lost = int(lives)  # game over: every life left is lost
            break
        lost = int(lives - info["lives"][0])
        frames.add(obs[0, -1].tobytes())
    envs.close()
    return lost, len(frames)


def test_no_fire_after_a_lost_life_and_the_papers_games_go_on_without_it():
    # docs/departures.md: unlike CleanRL's EpisodicLifeEnv + FireResetEnv, the script presses FIRE only when a game
    # starts. Breakout waits for FIRE to launch the next ball: the screen stands still under NOOPs until the
    # agent presses it, and then the ball is in play (and lost again).
    assert noops_after_a_lost_life("Breakout", fire_first=False) == (0, 1)
    lost, frames = noops_after_a_lost_life("Breakout", fire_first=True)
    assert lost == 1 and frames > 1
    # The ALE-5 games need no FIRE to go on after a lost life: the game moves under NOOPs.
    for game in ("BattleZone", "NameThisGame", "Phoenix", "Qbert"):
        lost, frames = noops_after_a_lost_life(game, fire_first=False)
        assert frames > 100, (game, lost, frames)
    # DoubleDunk has no lives to lose.
    import ppo_ultho_atari as script

    envs = script.make_envs(script.parse_args(["--env-id", "DoubleDunk", "--num-envs", "1"]), 1)
    _, info = envs.reset(seed=script.game_seeds(1, np.arange(1), np.zeros(1, dtype=int)))
    assert info["lives"][0] == 0
    envs.close()


# Every ALE-5 game, each named another way, and a game outside the ALE-5 (no human-normalized score).
GAMES = [("BattleZone", 2360.0), ("ALE/DoubleDunk-v5", -18.6), ("NameThisGame-v5", 2292.3), ("phoenix", 761.4),
         ("QbertNoFrameskip-v4", 163.9), ("Breakout", None)]


@pytest.fixture(scope="module")
def game_runs(tmp_path_factory):
    base = tmp_path_factory.mktemp("games")
    # 2 envs x 128 steps, two iterations; Breakout and Qbert games end within 256 steps, so those have a score.
    results = run_concurrently(SCRIPT, [
        ["--env-id", env_id, "--num-envs", "2", "--num-steps", "128", "--total-timesteps", "512", "--minibatch-size",
         "128", "--no-ultho", "--eval-episodes", "0", "--quiet", "--runs-dir", str(base), "--run-name", str(k)]
        for k, (env_id, _) in enumerate(GAMES)])
    return [(str(base / str(k)), result) for k, result in enumerate(results)]


@pytest.mark.parametrize("case", range(len(GAMES)), ids=[g for g, _ in GAMES])
def test_every_ale5_game_and_any_other_game_runs(game_runs, case):
    run_dir, result = game_runs[case]
    env_id, random_score = GAMES[case]
    assert result.returncode == 0, result.stderr
    s = summary(run_dir)
    assert s["env_id"] == env_id and s["global_step"] == 512
    if s["final_score"] is None or random_score is None:
        assert s["human_normalized_score"] is None
    else:
        assert (s["human_normalized_score"] < 0) == (s["final_score"] < random_score), s
    if env_id == "Breakout":  # its games are short: at least one ended, scored in whole points
        total = s["final_score"] * s["final_score_episodes"]
        assert s["final_score_episodes"] >= 1 and total == pytest.approx(round(total))


BAD_INPUTS = [
    (["--env-id", "NoSuchGame"], "NoSuchGame"),
    (["--env-id", "MiniGrid-DoorKey-6x6-v0"], "MiniGrid-DoorKey-6x6-v0"),
    (["--num-envs", "0"], "--num-envs must be positive, got 0"),
    (["--torch-threads", "-1"], "--torch-threads must be >= 0 (0: one per core), got -1"),
    (["--num-steps", "-3"], "--num-steps must be positive, got -3"),
    (["--num-steps", "abc"], "abc"),
    (["--minibatch-size", "300"], "300 does not divide"),
    (["--ultho-clusters", "momentum"], "momentum"),
    (["--ultho-clusters", "learning_rate"], "learning_rate"),
    (["--ultho-clusters", "minibatch_size=100,256"], "100 does not divide"),
    (["--ultho-clusters", "ent_coef=0.01,-1"], "-1"),
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
    (["--repeat-action-probability", "1.5"], "--repeat-action-probability must be in [0, 1], got 1.5"),
    (["--noop-max", "-1"], "--noop-max must be >= 0, got -1"),
    (["--resume", "/no/such/run"], "/no/such/run"),
    (["--init-from", "/no/such/run"], "--init-from /no/such/run: no checkpoint.pt there"),
    (["--resume", "/no/such/run", "--init-from", "/no/such/run"], "--resume and --init-from exclude each other"),
    (["--bogus-flag", "1"], "--bogus-flag"),
    (["--precision", "fp16"], "fp16"),
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
                 "--ultho-utility", "--resume", "--checkpoint-every", "--eval-episodes", "--quiet",
                 "--repeat-action-probability", "--noop-max", "--no-episodic-life", "--precision"):
        assert flag in result.stdout


@pytest.mark.parametrize("utility", ["return", "value-after"])
def test_other_utility_signals_credit_every_choice(tmp_path, utility):
    run_ok(SCRIPT, "--env-id", "Qbert", "--num-envs", "2", "--num-steps", "32", "--total-timesteps", "192",
           "--minibatch-size", "32", "--ultho-clusters", "minibatch_size=32,64", "vf_coef",
           "--ultho-utility", utility, "--eval-episodes", "0", "--runs-dir", str(tmp_path), "--run-name", "u")
    s = summary(str(tmp_path / "u"))
    credited = sum(s["bandit"]["selections"].values())
    # value-after credits within the iteration (all three), return credits at the next one (two of three).
    assert credited == (3 if utility == "value-after" else 2)
    credits = [v for _, v in scalars(str(tmp_path / "u"))["ultho/credit"]]
    assert len(credits) == credited and all(math.isfinite(c) for c in credits)


# Six iterations, a checkpoint every two: the authors' credit and the round robin, each killed and resumed.
SIX_ITERATIONS = ["--env-id", "Breakout", "--num-envs", "4", "--num-steps", "64", "--total-timesteps", "1536",
                  "--minibatch-size", "64", "--checkpoint-every", "2"]


def test_authors_credit_goes_to_the_choice_just_made_and_resumes_exactly(tmp_path):
    args = [*SIX_ITERATIONS, "--runs-dir", str(tmp_path)]
    assert_authors_credit_timing_and_exact_resume(SCRIPT, tmp_path, args)


def test_round_robin_takes_the_values_in_turn_and_resumes_exactly(tmp_path):
    args = [*SIX_ITERATIONS, "--runs-dir", str(tmp_path)]
    assert_round_robin_rotation_in_force_and_exact_resume(SCRIPT, tmp_path, args)

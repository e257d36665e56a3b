"""ppo_ultho_procgen.py, run for real on Procgen with tiny budgets (4 envs x 32 steps instead of 64 x 256)."""

import math
import os

import numpy as np
import pytest
import torch

from helpers import (
    assert_authors_credit_timing_and_exact_resume, assert_bf16_resume_equals_uninterrupted,
    assert_diverged_and_recorded, assert_existing_run_and_foreign_checkpoint_refused, assert_refused,
    assert_round_robin_rotation_in_force_and_exact_resume, bf16_against_float32, kill_after_first_checkpoint,
    real_rollout, run, run_bad_inputs, run_ok, scalars, summary,
)
from ultho_bandit import ULTHO

SCRIPT = "ppo_ultho_procgen.py"
GAMES = ["bigfish", "bossfight", "caveflyer", "chaser", "climber", "coinrun", "dodgeball", "fruitbot", "heist",
         "jumper", "leaper", "maze", "miner", "ninja", "plunder", "starpilot"]
# The paper's minibatch sizes (512-2048) do not divide a 128-sample rollout; the other clusters keep theirs.
SPACE = {"learning_rate": [2.5e-4, 5e-4, 1e-3], "minibatch_size": [32, 64, 128], "vf_coef": [0.25, 0.5, 1.0],
         "update_epochs": [3, 2, 1]}
TINY = ["--num-envs", "4", "--num-steps", "32", "--minibatch-size", "64", "--update-chunk", "48",
        "--ultho-clusters", "learning_rate", "minibatch_size=32,64,128", "vf_coef", "update_epochs"]
CHARTS = ["charts/episodic_return", "charts/episodic_length", "charts/SPS", "charts/learning_rate",
          "losses/value_loss", "losses/policy_loss", "losses/entropy", "losses/approx_kl", "losses/old_approx_kl",
          "losses/clipfrac", "losses/explained_variance"]


@pytest.fixture(scope="module")
def smoke_run(tmp_path_factory):
    # Three iterations with a test every iteration: tests at iterations 1 and 2, and the final one at 3.
    runs = tmp_path_factory.mktemp("runs")
    run_ok(SCRIPT, *TINY, "--total-timesteps", "384", "--eval-episodes", "3", "--eval-every", "1",
           "--runs-dir", str(runs), "--run-name", "smoke")
    return str(runs / "smoke")


def test_smoke_run_writes_every_tensorboard_tag(smoke_run):
    series = scalars(smoke_run)
    expected = (CHARTS + [f"hparams/{name}" for name in SPACE] + list(ULTHO(SPACE).scalars())
                + ["ultho/credit", "eval/return", "eval/test_return", "eval/normalized_test_return"])
    missing = [tag for tag in expected if tag not in series]
    assert not missing, f"missing tags: {missing}"
    assert [step for step, _ in series["ultho/selected_cluster"]] == [128, 256, 384]
    # Iteration 1 picks the first cluster's first value (every bound is 0): the paper's lowest learning rate.
    assert series["ultho/selected_cluster"][0][1] == 0.0
    assert series["hparams/learning_rate"][0][1] == pytest.approx(2.5e-4)
    assert series["charts/learning_rate"][0][1] == pytest.approx(2.5e-4)
    assert len(series["ultho/credit"]) == 2
    # --eval-every 1: a test after iterations 1 and 2, then the final one, which alone is also eval/return.
    assert [step for step, _ in series["eval/test_return"]] == [128, 256, 384]
    assert series["eval/return"] == [series["eval/test_return"][-1]]


def test_smoke_run_summary_has_train_and_test_scores(smoke_run):
    s = summary(smoke_run)
    assert s["script"] == "ppo_ultho_procgen" and s["env_id"] == "starpilot"
    assert s["precision"] == s["settings"]["precision"] == "float32"
    assert s["global_step"] == 384 and s["iterations"] == 3 and s["ultho"] is True
    assert s["settings"]["num_levels"] == 200 and s["settings"]["start_level"] == 0
    assert s["settings"]["gamma"] == 0.999 and s["settings"]["norm_reward"] is True
    assert s["wall_time_s"] > 0 and s["sps"] > 0 and s["peak_rss_mb"] > 0
    assert s["rollout_seconds"] > 0 and s["update_seconds"] > 0
    assert s["rollout_seconds"] + s["update_seconds"] < s["wall_time_s"]
    assert (s["peak_cuda_mb"] is None) == (s["device"] == "cpu")
    assert s["train_score"] == s["final_score"]
    assert s["eval"]["episodes"] == 3 and len(s["eval"]["returns"]) == 3
    assert s["test_score"] == pytest.approx(sum(s["eval"]["returns"]) / 3)
    # starpilot's easy-mode range is 2.5 .. 64.
    assert s["normalized_test_score"] == pytest.approx((s["test_score"] - 2.5) / 61.5)
    if s["train_score"] is not None:
        assert s["normalized_train_score"] == pytest.approx((s["train_score"] - 2.5) / 61.5)
    assert sum(s["bandit"]["selections"].values()) == 2  # the last selection is never credited
    assert s["bandit"]["search_space"] == SPACE
    checkpoint = torch.load(os.path.join(smoke_run, "checkpoint.pt"), weights_only=False)
    assert checkpoint["iteration"] == 3 and checkpoint["global_step"] == 384
    assert len(checkpoint["envs"]) == 4 and all(isinstance(state, bytes) for state in checkpoint["envs"])
    assert checkpoint["reward_normalizer"]["count"] > 384  # 1e-4 + one update per step, 4 returns each


def test_test_episodes_play_levels_outside_the_training_levels(smoke_run):
    # Training draws level seeds 0..199; the test environments draw from all 2^31 of them.
    seeds = summary(smoke_run)["eval"]["level_seeds"]
    assert len(seeds) == 3 and len(set(seeds)) == 3
    assert all(seed >= 200 for seed in seeds), seeds


def test_no_ultho_keeps_settings_fixed_and_logs_no_bandit_tags(tmp_path):
    run_ok(SCRIPT, "--num-envs", "4", "--num-steps", "32", "--minibatch-size", "64", "--total-timesteps", "256",
           "--no-ultho", "--learning-rate", "0.002", "--eval-episodes", "0", "--runs-dir", str(tmp_path),
           "--run-name", "ppo")
    series = scalars(str(tmp_path / "ppo"))
    assert not [tag for tag in series if tag.startswith("ultho/") or tag.startswith("eval/")]
    assert [v for _, v in series["hparams/learning_rate"]] == pytest.approx([0.002, 0.002])
    assert [v for _, v in series["hparams/minibatch_size"]] == [64, 64]
    assert [v for _, v in series["hparams/update_epochs"]] == [3, 3]
    s = summary(str(tmp_path / "ppo"))
    assert s["bandit"] is None and s["test_score"] is None and s["normalized_test_score"] is None
    assert s["settings_in_force"] == {"learning_rate": 0.002, "minibatch_size": 64, "vf_coef": 0.5, "update_epochs": 3}


def test_killed_and_resumed_run_equals_uninterrupted_run(tmp_path):
    # Equality needs the games' state (procgen's get_state bytes), the reward normalizer's statistics, the
    # bandit, the optimizer and every RNG to come back from the checkpoint.
    args = [*TINY, "--total-timesteps", "768", "--checkpoint-every", "2", "--eval-episodes", "2", "--quiet",
            "--runs-dir", str(tmp_path)]
    run_ok(SCRIPT, *args, "--run-name", "whole")
    kill_after_first_checkpoint(SCRIPT, str(tmp_path / "killed"), *args, "--run-name", "killed")
    checkpoint = torch.load(tmp_path / "killed" / "checkpoint.pt", weights_only=False)
    assert checkpoint["iteration"] < 6 and not (tmp_path / "killed" / "summary.json").exists()
    # The checkpoint is written right after an episode ended on the rollout's last step (environment 2).
    assert checkpoint["next_done"].any()
    run_ok(SCRIPT, "--resume", str(tmp_path / "killed"), "--quiet")

    whole, resumed = summary(str(tmp_path / "whole")), summary(str(tmp_path / "killed"))
    for key in ("global_step", "bandit", "settings_in_force", "train_score", "final_score_episodes", "eval",
                "test_score"):
        assert whole[key] == resumed[key], key
    a, b = scalars(str(tmp_path / "whole")), scalars(str(tmp_path / "killed"))
    for tag in ("ultho/selected_cluster", "ultho/selected_value", "ultho/credit", "losses/value_loss",
                "losses/policy_loss", "charts/episodic_return", "hparams/learning_rate", "charts/learning_rate"):
        assert a[tag] == b[tag], tag
    assert len(a["ultho/selected_cluster"]) == 6


def test_bf16_run_killed_and_resumed_continues_in_bf16_and_equals_uninterrupted_run(tmp_path):
    # The resume command leaves --precision out: bf16 must come back from the checkpoint, and bf16's kernels on
    # the CPU must be as repeatable as float32's. Plain PPO, so that the two continuations differ only in precision.
    args = ["--num-envs", "4", "--num-steps", "32", "--minibatch-size", "64", "--update-chunk", "48",
            "--total-timesteps", "512", "--no-ultho", "--checkpoint-every", "2", "--eval-episodes", "1", "--quiet",
            "--runs-dir", str(tmp_path)]
    assert_bf16_resume_equals_uninterrupted(SCRIPT, tmp_path, args, "train_score")


@pytest.mark.parametrize("seed", [1])
def test_bf16_gradient_agrees_with_float32_on_a_real_rollout(seed):
    # A minibatch of 512 starpilot frames (8 envs x 64 steps) played by the freshly initialized network, the PPO
    # loss computed by the script's own ppo_loss under both precisions with the same weights. Measured on seeds
    # 1-6 (docs/precision.md): cosine 0.9999-1.0000, relative norm difference 0.005-0.012, ratio deviation
    # 6e-6 to 9e-6; the bounds are the ALE test's, which a log-softmax left in bf16 fails.
    import ppo_ultho_procgen as script

    torch.manual_seed(seed)
    args = script.parse_args(["--num-envs", "8", "--num-steps", "64", "--seed", str(seed)])
    envs = script.make_envs(args, args.num_envs, test=False, seed=seed)
    agent = script.Agent(envs.single_observation_shape, envs.single_action_n, "float32")
    batch = real_rollout(script, agent, envs, envs.observation(), args)
    envs.close()
    agreement = bf16_against_float32(script, agent, args, batch)
    assert agreement["cosine"] > 0.99, agreement
    assert 0 < agreement["relative_norm_difference"] < 0.15, agreement  # > 0: bf16 was in effect
    assert 0 < agreement["ratio_deviation"] < 1e-3, agreement


def test_non_finite_loss_stops_the_run_and_its_summary_records_it(tmp_path):
    # Iteration 1 takes lr=1e-3 (every bound is 0); with c=100 iteration 2 explores the untried 1e38.
    result = run(SCRIPT, "--num-envs", "4", "--num-steps", "32", "--minibatch-size", "64", "--total-timesteps", "384",
                 "--ultho-clusters", "learning_rate=0.001,1e38", "--ultho-c", "100", "--checkpoint-every", "1",
                 "--runs-dir", str(tmp_path), "--run-name", "nan")
    recorded = assert_diverged_and_recorded(result, tmp_path / "nan", 2, "learning_rate=1e+38", "agent")
    assert recorded["diverged"]["what"] == "loss" and recorded["settings_in_force"]["learning_rate"] == 1e38


def test_neighbouring_runs_test_on_different_levels():
    # procgen draws each test environment's levels from its own generator seeded by the run's seed, so runs with
    # seeds 1 and 2 share no test level (the level seeds range over 2^31), and none is a training level.
    import ppo_ultho_procgen as script

    levels = {}
    for seed in (1, 2):
        torch.manual_seed(seed)
        args = script.parse_args(["--env-id", "coinrun", "--seed", str(seed), "--eval-episodes", "10"])
        agent = script.Agent((64, 64, 3), 15, "float32")
        levels[seed] = set(script.evaluate(agent, args, torch.device("cpu"), 3)[1])
        assert len(levels[seed]) == 10
    assert not levels[1] & levels[2]
    assert min(levels[1] | levels[2]) >= 200


def test_reward_normalizer_zeroes_a_finished_episodes_return_after_normalizing_its_last_reward():
    # gym's NormalizeReward (CleanRL's ppo_procgen.py) by hand: two environments, gamma 0.5, the running statistics
    # starting at mean 0, variance 1 from a count of 1e-4; environment 0's episode ends at step 2.
    from ppo_ultho_procgen import RewardNormalizer

    normalizer = RewardNormalizer(num_envs=2, gamma=0.5)

    # Step 1: rewards (1, 0), nothing ends. Discounted returns (1, 0): batch mean 0.5, variance 0.25, 2 samples.
    rewards = normalizer(np.array([1.0, 0.0]), np.array([False, False]))
    count = 1e-4 + 2
    mean = 0.5 * 2 / count
    var = (1.0 * 1e-4 + 0.25 * 2 + 0.5**2 * 1e-4 * 2 / count) / count
    np.testing.assert_allclose(rewards, [1.0 / math.sqrt(var + 1e-8), 0.0], rtol=1e-12)
    np.testing.assert_array_equal(normalizer.returns, [1.0, 0.0])

    # Step 2: rewards (2, 0), environment 0's episode ends with this reward. Its last reward still counts in its
    # own return, 0.5 * 1 + 2 = 2.5: returns (2.5, 0), batch mean 1.25, variance 1.5625 (the early reset gave
    # (2, 0)). Only then is its return zeroed.
    rewards = normalizer(np.array([2.0, 0.0]), np.array([True, False]))
    delta, previous_count, count = 1.25 - mean, count, count + 2
    mean = mean + delta * 2 / count
    var = (var * previous_count + 1.5625 * 2 + delta**2 * previous_count * 2 / count) / count
    np.testing.assert_allclose(rewards, [2.0 / math.sqrt(var + 1e-8), 0.0], rtol=1e-12)
    np.testing.assert_array_equal(normalizer.returns, [0.0, 0.0])

    # Step 3: rewards (4, 1). The new episode's return is its own reward alone, 4 (the early reset gave
    # 0.5 * 2 + 4 = 5: the last episode's final reward leaked in); environment 1's goes on, 0.5 * 0 + 1 = 1.
    # Returns (4, 1): batch mean 2.5, variance 2.25.
    rewards = normalizer(np.array([4.0, 1.0]), np.array([False, False]))
    delta, previous_count, count = 2.5 - mean, count, count + 2
    mean = mean + delta * 2 / count
    var = (var * previous_count + 2.25 * 2 + delta**2 * previous_count * 2 / count) / count
    np.testing.assert_array_equal(normalizer.returns, [4.0, 1.0])
    np.testing.assert_allclose(rewards, np.array([4.0, 1.0]) / math.sqrt(var + 1e-8), rtol=1e-12)
    assert normalizer.count == count and math.isclose(normalizer.mean, mean, rel_tol=1e-12)


def test_reward_normalizer_equals_gyms_normalize_reward_over_many_episodes():
    # The old gym that procgen installs has the wrapper CleanRL's ppo_procgen.py uses; fed the same rewards and
    # episode ends (an environment that replays them), it must give the same normalized rewards, clipped to +-10
    # as CleanRL's TransformReward does after it.
    import gym
    from gym.wrappers import NormalizeReward

    from ppo_ultho_procgen import RewardNormalizer

    generator = np.random.default_rng(0)
    steps = [(generator.normal(0, 3, size=4) * (generator.random(4) < 0.3), generator.random(4) < 0.1)
             for _ in range(300)]
    steps.append((np.array([1000.0, 0.0, 0.0, 0.0]), np.zeros(4, bool)))  # far beyond 10 standard deviations

    class Replay(gym.Env):
        num_envs, is_vector_env = 4, True

        def __init__(self):
            self.steps = iter(steps)

        def step(self, action):
            reward, done = next(self.steps)
            return None, reward, done, np.zeros(4, bool), {}

    gyms, ours = NormalizeReward(Replay(), gamma=0.999), RewardNormalizer(4, gamma=0.999)
    for reward, done in steps:
        expected = np.clip(gyms.step(None)[1], -10, 10)
        np.testing.assert_allclose(ours(reward, done), expected, rtol=1e-12, atol=0)
        np.testing.assert_allclose(ours.returns, gyms.returns, rtol=1e-12, atol=0)
    assert expected[0] == 10.0


BAD_INPUTS = [
    (["--env-id", "pong"], "pong"),
    (["--env-id", "starpilot-v0"], "starpilot-v0"),
    (["--num-envs", "0"], "--num-envs must be positive, got 0"),
    (["--torch-threads", "-1"], "--torch-threads must be >= 0 (0: one per core), got -1"),
    (["--num-steps", "abc"], "abc"),
    (["--num-levels", "-1"], "--num-levels must be >= 0, got -1"),
    (["--start-level", "-5"], "--start-level must be >= 0, got -5"),
    (["--eval-every", "-1"], "--eval-every must be >= 0, got -1"),
    (["--eval-episodes", "-1"], "--eval-episodes must be >= 0, got -1"),
    (["--update-chunk", "-1"], "--update-chunk must be >= 0 (0: automatic), got -1"),
    (["--env-threads", "-1"], "--env-threads must be >= 0, got -1"),
    (["--minibatch-size", "3000"], "3000 does not divide"),
    (["--ultho-clusters", "momentum"], "momentum"),
    (["--ultho-clusters", "minibatch_size=1000,2048"], "1000 does not divide"),
    (["--ultho-clusters", "update_epochs=3,0"], "update_epochs must be a positive integer, got 0"),
    (["--ultho-c", "-1"], "--ultho-c must be a finite number >= 0, got -1.0"),
    (["--ultho-strategy", "greedy"], "greedy"),
    (["--ultho-credit", "delta"], "delta"),
    (["--ultho-exp3-eta", "0"], "--ultho-exp3-eta must be a finite number > 0, got 0.0"),
    (["--ultho-utility", "reward"], "reward"),
    (["--total-timesteps", "100"], "--total-timesteps 100"),
    (["--gamma", "1.5"], "--gamma must be in (0, 1], got 1.5"),
    (["--resume", "/no/such/run"], "/no/such/run"),
    (["--init-from", "/no/such/run"], "--init-from /no/such/run: no checkpoint.pt there"),
    (["--resume", "/no/such/run", "--init-from", "/no/such/run"], "--resume and --init-from exclude each other"),
    (["--run-name", "a/b"], "'a/b'"),
    (["--precision", "fp16"], "fp16"),
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
    for flag in ("--env-id", "--num-levels", "--start-level", "--total-timesteps", "--minibatch-size",
                 "--update-chunk", "--env-threads", "--norm-reward", "--ultho-clusters", "--no-ultho",
                 "--ultho-utility", "--resume",
                 "--checkpoint-every", "--eval-episodes", "--eval-every", "--quiet", "--precision"):
        assert flag in result.stdout


@pytest.mark.parametrize("utility", ["return", "value-after"])
def test_other_utility_signals_credit_every_choice(tmp_path, utility):
    run_ok(SCRIPT, *TINY, "--total-timesteps", "384", "--ultho-utility", utility, "--eval-episodes", "0",
           "--runs-dir", str(tmp_path), "--run-name", "u")
    s = summary(str(tmp_path / "u"))
    credited = sum(s["bandit"]["selections"].values())
    # value-after credits within the iteration (all three), return credits at the next one (two of three).
    assert credited == (3 if utility == "value-after" else 2)
    credits = [v for _, v in scalars(str(tmp_path / "u"))["ultho/credit"]]
    assert len(credits) == credited and all(math.isfinite(c) for c in credits)


def test_games_are_named_and_the_refusal_lists_all_sixteen(bad_input_results):
    _, result = bad_input_results[0]  # --env-id pong
    assert all(game in result.stderr for game in GAMES), result.stderr


@pytest.mark.parametrize("game", ["coinrun", "maze", "bigfish"])
def test_other_procgen_games_train_by_name(tmp_path, game):
    # A platformer, a maze and a game that grows the agent: different observation content, same pipeline.
    run_ok(SCRIPT, "--env-id", game, "--num-envs", "2", "--num-steps", "16", "--minibatch-size", "32",
           "--total-timesteps", "32", "--ultho-clusters", "learning_rate", "vf_coef", "update_epochs",
           "--eval-episodes", "1", "--quiet", "--runs-dir", str(tmp_path), "--run-name", game)
    s = summary(str(tmp_path / game))
    assert s["env_id"] == game and s["global_step"] == 32 and s["eval"]["episodes"] == 1


def test_update_chunk_zero_is_the_whole_minibatch_on_cuda_and_at_most_512_on_the_cpu():
    import ppo_ultho_procgen as script

    cpu, cuda = torch.device("cpu"), torch.device("cuda")
    assert script.Args().update_chunk == 0
    for minibatch_size, on_the_cpu in ((2048, 512), (1024, 512), (512, 512), (256, 256)):
        automatic = script.Args(minibatch_size=minibatch_size)
        assert script.update_chunk_size(automatic.update_chunk, minibatch_size, cpu) == on_the_cpu
        assert script.update_chunk_size(automatic.update_chunk, minibatch_size, cuda) == minibatch_size
    explicit = script.Args(minibatch_size=2048, update_chunk=48)
    assert (script.update_chunk_size(explicit.update_chunk, explicit.minibatch_size, cpu)
            == script.update_chunk_size(explicit.update_chunk, explicit.minibatch_size, cuda) == 48)


def test_env_threads_reach_procgen_and_do_not_change_the_games():
    import ppo_ultho_procgen as script

    actions = np.random.default_rng(0).integers(0, 15, (100, 4))
    games = []
    for threads in (0, 1, 3):
        before = len(os.listdir("/proc/self/task"))
        envs = script.make_envs(script.Args(env_threads=threads), 4, test=False, seed=7)
        assert len(os.listdir("/proc/self/task")) - before == threads  # 0: stepped in the caller's thread
        played = [envs.observation()]
        for a in actions:
            obs, reward, terminated, _, _ = envs.step(a)
            played += [obs.copy(), reward.copy(), terminated.copy()]
        assert any(x.any() for x in played[3::3]), "no game ended: the comparison would miss resets"
        games.append(played)
        del envs
    for other in games[1:]:
        assert all(np.array_equal(x, y) for x, y in zip(games[0], other))


# Six iterations, a checkpoint every two: the authors' credit and the round robin, each killed and resumed.
SIX_ITERATIONS = ["--num-envs", "4", "--num-steps", "32", "--minibatch-size", "64", "--update-chunk", "48",
                  "--total-timesteps", "768", "--checkpoint-every", "2"]


def test_authors_credit_goes_to_the_choice_just_made_and_resumes_exactly(tmp_path):
    args = [*SIX_ITERATIONS, "--runs-dir", str(tmp_path)]
    assert_authors_credit_timing_and_exact_resume(SCRIPT, tmp_path, args)


def test_round_robin_takes_the_values_in_turn_and_resumes_exactly(tmp_path):
    args = [*SIX_ITERATIONS, "--runs-dir", str(tmp_path)]
    assert_round_robin_rotation_in_force_and_exact_resume(SCRIPT, tmp_path, args)

"""Tracking, videos and evaluating a finished run, in every script: --track mirrors a run to Weights & Biases (read
back from W&B's offline files), --capture-video writes MP4s whose frames are the environment's (read back with
PyAV), --evaluate replays the final evaluation exactly and writes nothing; bad input is refused in one line."""

import ctypes.util
import json
import os
import shutil
import subprocess
import sys

import av
import numpy as np
import pytest
import torch

from helpers import (REPO, assert_refused, kill_after_first_checkpoint, run, run_ok, scalars, summary,
                     wandb_history, wandb_offline_runs, without_wandb_login)

# A tiny run of each script: a few iterations, a short final evaluation.
TINY = {
    "ppo_ultho_minigrid.py": ["--num-envs", "8", "--num-steps", "64", "--total-timesteps", "1024",
                              "--minibatch-size", "128", "--eval-episodes", "2"],
    "ppo_ultho_atari.py": ["--env-id", "Qbert", "--num-envs", "4", "--num-steps", "128", "--total-timesteps", "1024",
                           "--eval-episodes", "2"],
    "ppo_ultho_procgen.py": ["--num-envs", "4", "--num-steps", "32", "--minibatch-size", "64", "--update-chunk", "48",
                             "--ultho-clusters", "learning_rate", "minibatch_size=32,64,128", "vf_coef",
                             "update_epochs", "--total-timesteps", "256", "--eval-episodes", "2"],
    "ppo_ultho_pybullet.py": ["--env-id", "HopperBulletEnv-v0", "--num-steps", "256", "--total-timesteps", "512",
                              "--update-epochs", "2", "--eval-episodes", "3"],
    "sac_ultho_dmc.py": ["--env-id", "cheetah-run", "--total-timesteps", "200", "--ultho-interval", "100",
                         "--learning-starts", "100", "--ultho-clusters", "q_lr", "policy_lr", "batch_size=16,32,64",
                         "tau", "--batch-size", "32", "--eval-episodes", "1"],
}
SCRIPTS = list(TINY)
# DMC renders through an off-screen OpenGL (Debian's EGL or OSMesa); the other benchmarks need none.
DMC_RENDERS = bool(ctypes.util.find_library("EGL") or ctypes.util.find_library("OSMesa"))
VIDEO = {script: script != "sac_ultho_dmc.py" or DMC_RENDERS for script in SCRIPTS}
OFFLINE = {"WANDB_MODE": "offline", "WANDB_SILENT": "true"}


def video_frames(path) -> list[np.ndarray]:
    with av.open(str(path)) as container:
        return [frame.to_ndarray(format="rgb24") for frame in container.decode(video=0)]


def files_and_times(run_dir) -> dict[str, float]:
    return {os.path.join(d, f): os.path.getmtime(os.path.join(d, f)) for d, _, names in os.walk(run_dir)
            for f in names}


@pytest.fixture(scope="module")
def recorded_runs(tmp_path_factory):
    """Each script's tiny run with --capture-video, all at once: {script: run directory}."""
    base = tmp_path_factory.mktemp("recorded")
    processes = {script: subprocess.Popen([sys.executable, os.path.join(REPO, script), *TINY[script], "--runs-dir",
                                           str(base), "--run-name", script, "--quiet",
                                           *(["--capture-video"] if VIDEO[script] else [])],
                                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
                 for script in SCRIPTS}
    for script, process in processes.items():
        _, stderr = process.communicate(timeout=600)
        assert process.returncode == 0, f"{script}: {stderr}"
    return {script: base / script for script in SCRIPTS}


@pytest.mark.parametrize("script", SCRIPTS)
def test_evaluate_replays_the_final_evaluation_and_writes_nothing(recorded_runs, script):
    run_dir = recorded_runs[script]
    before = files_and_times(run_dir)
    result = run_ok(script, "--evaluate", str(run_dir), "--eval-episodes", str(summary(run_dir)["eval"]["episodes"]))
    assert files_and_times(run_dir) == before
    first, second = result.stdout.strip().splitlines()
    returns = json.loads(second.split("returns: ", 1)[1])
    assert returns == summary(run_dir)["eval"]["returns"]  # the same episodes, the same actions
    assert f"mean return {np.mean(returns):.4g} ± {np.std(returns):.4g} over {len(returns)} episodes" in first


@pytest.mark.parametrize("script", SCRIPTS)
def test_final_video_shows_the_environment(recorded_runs, script):
    if not VIDEO[script]:
        pytest.skip("no off-screen OpenGL for MuJoCo here (Debian's libegl1, libegl-mesa0, libgl1-mesa-dri)")
    run_dir = recorded_runs[script]
    [name] = os.listdir(run_dir / "videos")
    assert name == f"final-step{summary(run_dir)['global_step']}.mp4"
    frames = video_frames(run_dir / "videos" / name)
    assert len(frames) > 5
    assert frames[0].ndim == 3 and frames[0].shape[2] == 3 and min(frames[0].shape[:2]) >= 64
    assert all(frame.std() > 5 for frame in frames)  # pictures, not a blank screen
    assert max(np.abs(frame.astype(int) - frames[0]).mean() for frame in frames) > 0.5  # and something moves


def test_minigrid_video_is_the_first_evaluation_episode_whole(recorded_runs):
    # MiniGrid's rendering of the first evaluation episode's reset, and one frame per step to its last, the
    # terminal step included: a DoorKey-6x6 episode that fails lasts 360 steps, one that succeeds scores
    # 1 - 0.9 * steps / 360.
    import gymnasium as gym
    import minigrid  # noqa: F401

    import ppo_ultho_minigrid as script

    run_dir = recorded_runs["ppo_ultho_minigrid.py"]
    frames = video_frames(next((run_dir / "videos").iterdir()))
    env = gym.make("MiniGrid-DoorKey-6x6-v0", render_mode="rgb_array")
    env.reset(seed=script.episode_seed(1, 1, 0))
    first = env.render()
    assert frames[0].shape == first.shape == (192, 192, 3)
    assert np.abs(frames[0].astype(int) - first).mean() < 4  # H.264 is lossy; another layout differs by far more
    score = summary(run_dir)["eval"]["returns"][0]
    steps = 360 if score == 0 else round((1 - score) * 360 / 0.9)
    assert len(frames) == steps + 1


def test_evaluate_with_capture_video_writes_its_video_and_nothing_else(recorded_runs, tmp_path):
    script = "ppo_ultho_minigrid.py"
    run_dir = tmp_path / "copy"
    shutil.copytree(recorded_runs[script], run_dir)
    before = files_and_times(run_dir)
    result = run_ok(script, "--evaluate", str(run_dir), "--eval-episodes", "2", "--capture-video")
    video = run_dir / "videos" / "evaluate-step1024.mp4"
    assert files_and_times(run_dir).keys() - before.keys() == {str(video)}
    assert all(files_and_times(run_dir)[path] == time for path, time in before.items())
    assert f"video {video}" in result.stdout
    # The same first episode as the final evaluation's video, frame for frame (decoded: H.264 is lossy alike).
    final = video_frames(run_dir / "videos" / "final-step1024.mp4")
    assert len(video_frames(video)) == len(final)
    assert all(np.array_equal(a, b) for a, b in zip(video_frames(video), final))


def test_video_every_records_during_training_and_changes_nothing(tmp_path):
    script = "ppo_ultho_minigrid.py"
    plain = tmp_path / "plain"
    run_ok(script, *TINY[script], "--runs-dir", str(tmp_path), "--run-name", "plain", "--checkpoint-every", "100",
           "--quiet")
    run_ok(script, *TINY[script], "--runs-dir", str(tmp_path), "--run-name", "filmed", "--capture-video",
           "--video-every", "1", "--quiet")
    filmed = tmp_path / "filmed"
    assert sorted(os.listdir(filmed / "videos")) == ["final-step1024.mp4", "iteration1-step512.mp4"]
    assert summary(filmed)["final_score"] == summary(plain)["final_score"]
    assert summary(filmed)["eval"] == summary(plain)["eval"]
    agents = [torch.load(run_dir / "checkpoint.pt", weights_only=False)["agent"] for run_dir in (plain, filmed)]
    assert all(torch.equal(agents[0][k], agents[1][k]) for k in agents[0])


def test_track_mirrors_config_scalars_code_and_video_and_a_resumed_run_continues_it(tmp_path):
    script = "ppo_ultho_minigrid.py"
    wandb_dir = tmp_path / "wandb"
    wandb_dir.mkdir()
    env = {**OFFLINE, "WANDB_DIR": str(wandb_dir)}
    run_dir = tmp_path / "tracked"
    args = [*TINY[script], "--total-timesteps", "2048", "--checkpoint-every", "2", "--runs-dir", str(tmp_path),
            "--run-name", "tracked", "--track", "--wandb-project-name", "ultho-tests", "--wandb-group", "g1",
            "--capture-video", "--quiet"]
    os.environ.update(env)  # kill_after_first_checkpoint starts the process with this environment
    try:
        kill_after_first_checkpoint(script, str(run_dir), *args)
    finally:
        for name in env:
            os.environ.pop(name)
    run_id = (run_dir / "wandb_id").read_text().strip()
    result = run(script, "--resume", str(run_dir), "--quiet", env=env)
    assert result.returncode == 0, result.stderr
    assert (run_dir / "wandb_id").read_text().strip() == run_id
    runs = wandb_offline_runs(wandb_dir)
    assert list(runs) == [run_id]  # the resumed process logged to the same W&B run
    records = runs[run_id]
    # The killed process's own W&B file may end before its run record reached it; the resumed one's says so.
    starts = [r.run for r in records if r.WhichOneof("record_type") == "run"]
    assert starts[-1].resume and {(s.display_name, s.project, s.run_group) for s in starts} == {
        ("tracked", "ultho-tests", "g1")}
    config = {item.key: json.loads(item.value_json) for item in starts[0].config.update}
    assert config["ultho_c"] == 5.0 and config["ultho_clusters"] == ["learning_rate", "minibatch_size", "vf_coef"]
    assert config["total_timesteps"] == 2048 and config["track"] is True
    history = wandb_history(records)
    events = scalars(str(run_dir))
    for tag in ("ultho/selected_cluster", "ultho/credit", "hparams/learning_rate", "losses/value_loss",
                "eval/return"):
        # Every value the resumed process logged reached W&B (what the killed one had logged reached it only as
        # far as W&B's own service, killed with it, had written it).
        # (Both as TensorBoard's float32: W&B writes a float32 with its shortest decimal.)
        after = {(step, np.float32(value)) for step, value in events[tag] if step > 1024}  # the checkpoint's step
        assert after and after <= {(step, np.float32(value)) for step, value in history[tag]}, tag
    files = {f.path for r in records if r.WhichOneof("record_type") == "files" for f in r.files.files}
    assert f"code/{script}" in files
    assert any(path.startswith("media/videos/") and path.endswith(".mp4") for path in files)


def start(script: str, args: list[str], runs_dir, env: dict) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, os.path.join(REPO, script), "--runs-dir", str(runs_dir), *args],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO, env=env)



BAD = [
    (["--video-every", "-1"], "--video-every must be >= 0"),
    (["--video-every", "3"], "--video-every 3 records videos: add --capture-video"),
    (["--capture-video", "--eval-episodes", "0"], "--eval-episodes 0 runs none"),
    (["--wandb-entity", "me"], "add --track"),
    (["--track", "--wandb-project-name", "a/b"], "--wandb-project-name 'a/b'"),
    (["--track"], "WANDB_MODE=offline"),
    (["--evaluate", "/no/such/run"], "--evaluate /no/such/run: no checkpoint.pt there"),
    (["--evaluate", "/no/such/run", "--resume", "/no/such/run"], "--evaluate plays a run's policy"),
    (["--evaluate", "RUN", "--eval-episodes", "0"], "--eval-episodes"),
    (["--evaluate", "FOREIGN"], "is not a"),
]


@pytest.mark.parametrize("script", SCRIPTS)
def test_bad_input_exits_2_with_one_line_and_writes_nothing(recorded_runs, script, tmp_path):
    other = next((s for s in recorded_runs if s != script), None)
    processes = []
    for k, (args, named) in enumerate(BAD):
        if "FOREIGN" in args and other is None:
            continue
        args = [{"RUN": str(recorded_runs[script]), "FOREIGN": str(recorded_runs.get(other, ""))}.get(a, a)
                for a in args]
        env = without_wandb_login(tmp_path) if args == ["--track"] else {**os.environ, **OFFLINE}
        processes.append((tmp_path / f"runs{k}", named, start(script, args, tmp_path / f"runs{k}", env)))
    for runs_dir, named, process in processes:
        stdout, stderr = process.communicate(timeout=300)
        assert_refused(script, str(runs_dir), subprocess.CompletedProcess(process.args, process.returncode, stdout,
                                                                           stderr), named)


def test_dmc_video_without_a_renderer_is_refused_before_training(tmp_path):
    env = {**os.environ, "MUJOCO_GL": "disabled"}  # what a machine without EGL and OSMesa gets
    process = start("sac_ultho_dmc.py", ["--capture-video"], tmp_path / "runs", env)
    stdout, stderr = process.communicate(timeout=300)
    assert_refused("sac_ultho_dmc.py", str(tmp_path / "runs"),
                   subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr),
                   "--capture-video: cheetah-run cannot be rendered here with MUJOCO_GL=disabled")

"""sweep.py: the paper presets' expansion, a local sweep, the same through a real Ray instance, kill and restart."""

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time

import pytest

from helpers import (REPO, files_under, run, run_concurrently, summary, wandb_history, wandb_offline_runs,
                     without_wandb_login)

TOOL = "sweep.py"
SCRIPT = "ppo_ultho_minigrid.py"
# Two iterations of 4 envs x 64 steps on Empty-5x5 (every episode ends); the first selection, learning_rate,
# is the only credited one, so a relay's COI is learning_rate and its NOI minibatch_size.
TINY = ["--scripts", SCRIPT, "--env-ids", "MiniGrid-Empty-5x5-v0", "--total-timesteps", "512", "--", "--num-envs", "4",
        "--num-steps", "64", "--minibatch-size", "64", "--ultho-clusters", "learning_rate", "minibatch_size=32,64",
        "--eval-episodes", "0"]
RUN_FIELDS = {"name", "script", "benchmark", "env_id", "method", "c", "window", "variant", "settings", "seed", "path",
              "status", "attempts", "error"}



def index(out) -> dict:
    with open(os.path.join(out, "sweep.json")) as f:
        return json.load(f)


def events(run_dir) -> list[str]:
    return [f for f in os.listdir(run_dir) if f.startswith("events.out.tfevents")]


@pytest.mark.parametrize("preset, envs, budget", [("procgen", 16, 25_000_000), ("atari", 5, 10_000_000),
                                                  ("minigrid", 3, 500_000), ("pybullet", 4, 2_000_000)])
def test_paper_preset_dry_run_expands_the_papers_grid(preset, envs, budget, tmp_path):
    result = run(TOOL, "--paper", preset, "--dry-run", "--out", str(tmp_path / "s"))
    assert result.returncode == 0, result.stderr
    commands = result.stdout.strip().splitlines()
    per_env_seed = 1 + 6 + 6  # ppo, ultho at each (c, W) in {1, 5} x {10, 50, 100}, relay at each
    assert len(commands) == envs * 5 * per_env_seed
    assert len({c for c in commands}) == len(commands)
    assert sum("--no-ultho" in c for c in commands) == envs * 5
    relays = [c for c in commands if "relay_ultho.py" in c]
    assert len(relays) == envs * 5 * 6 and all(" --from " in c for c in relays)
    assert all(f"ppo_ultho_{preset}.py" in c and f"--total-timesteps {budget}" in c for c in commands)
    for c_value in ("1.0", "5.0"):
        for window in ("10", "50", "100"):
            assert sum(f"--ultho-c {c_value} --ultho-window {window} " in c + " " for c in commands) == 2 * envs * 5
    for seed in range(1, 6):
        assert sum(f" --seed {seed} " in c for c in commands) == envs * per_env_seed
    # The relay reuses its ULTHO run, so a grid point costs 1 + 6 + 6 * 2 runs of the budget.
    assert f"{len(commands)} runs, {envs * 5 * 19 * budget:,} environment steps" in result.stderr
    assert not (tmp_path / "s").exists()


def test_points_give_the_c_w_pairs_instead_of_the_product(tmp_path):
    """The paper's MiniGrid protocol: PPO, ULTHO and Relay-ULTHO at (c, W) = (5, 10) and (1, 50) only."""
    result = run(TOOL, "--paper", "minigrid", "--points", "5:10", "1:50", "--dry-run", "--out", str(tmp_path / "s"))
    assert result.returncode == 0, result.stderr
    commands = result.stdout.strip().splitlines()
    assert len(commands) == 3 * 5 * (1 + 2 + 2)
    for pair in ("--ultho-c 5.0 --ultho-window 10 ", "--ultho-c 1.0 --ultho-window 50 "):
        assert sum(pair in c + " " for c in commands) == 2 * 3 * 5
    assert not any("--ultho-c 1.0 --ultho-window 10 " in c + " " for c in commands)
    assert f"75 runs, {3 * 5 * (1 + 2 + 2 * 2) * 500_000:,} environment steps" in result.stderr


def test_dry_run_of_a_custom_grid_counts_steps_without_an_hours_estimate(tmp_path):
    result = run(TOOL, "--scripts", SCRIPT, "--env-ids", "MiniGrid-Empty-5x5-v0", "--methods", "ppo", "pbt",
                 "--population", "2", "--total-timesteps", "1024", "--dry-run", "--out", str(tmp_path / "s"))
    assert result.returncode == 0, result.stderr
    assert result.stderr.strip() == f"2 runs, {1024 + 2 * 1024:,} environment steps"


def test_the_grid_method_is_every_fixed_setting_of_the_search_space(tmp_path):
    result = run(TOOL, "--paper", "minigrid", "--methods", "grid", "--env-ids", "MiniGrid-DoorKey-6x6-v0", "--seeds",
                 "1", "--dry-run", "--out", str(tmp_path / "s"))
    assert result.returncode == 0, result.stderr
    commands = result.stdout.strip().splitlines()
    assert len(commands) == 27 and result.stderr.strip().startswith(f"27 runs, {27 * 500_000:,} environment steps")
    # The first cluster varies slowest; each run is the script with --no-ultho and its three values.
    assert "--no-ultho --learning-rate 0.001 --minibatch-size 128 --vf-coef 0.25 --quiet" in commands[0]
    assert "--no-ultho --learning-rate 0.001 --minibatch-size 128 --vf-coef 0.5 --quiet" in commands[1]
    assert "--no-ultho --learning-rate 0.005 --minibatch-size 512 --vf-coef 1.0 --quiet" in commands[26]
    assert commands[26].endswith(
        "--run-name minigrid__MiniGrid-DoorKey-6x6-v0__grid_learning_rate-0.005_minibatch_size-512_vf_coef-1.0__s1")
    assert len({c.split("--run-name ")[1] for c in commands}) == 27
    chosen = run(TOOL, "--paper", "pybullet", "--methods", "grid", "--grid-clusters", "update_epochs=10,5",
                 "learning_rate", "--env-ids", "HopperBulletEnv-v0", "--seeds", "1", "--dry-run")
    assert chosen.returncode == 0, chosen.stderr
    assert [c.split("--no-ultho ")[1].split(" --quiet")[0] for c in chosen.stdout.strip().splitlines()] == [
        f"--update-epochs {e} --learning-rate {lr}" for e in (10, 5) for lr in ("0.0002", "0.0005", "0.0007")]


def test_a_grid_sweep_runs_each_fixed_setting(tmp_path):
    out = tmp_path / "grid"
    result = run(TOOL, "--scripts", SCRIPT, "--env-ids", "MiniGrid-Empty-5x5-v0", "--methods", "grid",
                 "--grid-clusters", "minibatch_size=32,64", "vf_coef=0.5,1.0", "--total-timesteps", "512", "--workers",
                 "2", "--out", str(out), "--", "--num-envs", "4", "--num-steps", "64", "--eval-episodes", "0")
    assert result.returncode == 0, result.stderr
    record = index(out)
    assert [r["settings"] for r in record["runs"]] == [{"minibatch_size": 32, "vf_coef": 0.5},
                                                       {"minibatch_size": 32, "vf_coef": 1.0},
                                                       {"minibatch_size": 64, "vf_coef": 0.5},
                                                       {"minibatch_size": 64, "vf_coef": 1.0}]
    for entry in record["runs"]:
        assert entry["method"] == "grid" and entry["status"] == "done"
        done = summary(os.path.join(out, entry["path"]))
        assert done["ultho"] is False and done["bandit"] is None
        assert {name: done["settings"][name] for name in entry["settings"]} == entry["settings"]
        assert {name: done["settings_in_force"][name] for name in entry["settings"]} == entry["settings"]
    assert record["grid"]["grid_clusters"] == ["minibatch_size=32,64", "vf_coef=0.5,1.0"]


def test_variants_name_their_runs_and_pass_their_options(tmp_path):
    result = run(TOOL, "--paper", "minigrid", "--points", "5:10",
                 "--variants", "ucb:level:none", "ts:improvement:running",
                 "--env-ids", "MiniGrid-DoorKey-6x6-v0", "--seeds", "1", "--dry-run", "--out", str(tmp_path / "s"))
    assert result.returncode == 0, result.stderr
    commands = result.stdout.strip().splitlines()
    assert len(commands) == 1 + 2 * 2
    paper = [c for c in commands if "ultho_c5.0_w10__s1" in c]
    variant = [c for c in commands if "ts-improvement-running_c5.0_w10__s1" in c]
    assert len(paper) == len(variant) == 2  # the ULTHO run and the relay that reuses it
    assert not any("--ultho-strategy" in c for c in paper)
    assert all("--ultho-strategy ts --ultho-credit improvement --ultho-scale running" in c for c in variant)


def test_hpo_methods_are_studies_of_the_population_in_the_dry_run(tmp_path):
    result = run(TOOL, "--paper", "minigrid", "--methods", "ppo", "pbt", "pb2", "random", "--seeds", "1",
                 "--population", "3", "--dry-run", "--out", str(tmp_path / "s"))
    assert result.returncode == 0, result.stderr
    commands = result.stdout.strip().splitlines()
    assert len(commands) == 3 * 4
    for method, size in (("pbt", "--population 3"), ("pb2", "--population 3"), ("random", "--samples 3")):
        studies = [c for c in commands if f"hpo_baselines.py ppo_ultho_minigrid.py --method {method} " in c]
        assert len(studies) == 3 and all(f"{size} --seed 1 --num-cpus 1 --study-dir " in c for c in studies)
        assert all(" -- --env-id MiniGrid-" in c and c.endswith("--total-timesteps 500000") for c in studies)
    # PPO is one run of the budget per environment, each study three.
    assert f"12 runs, {3 * (1 + 3 * 3) * 500_000:,} environment steps" in result.stderr


def test_track_adds_the_wandb_flags_to_every_command_and_nothing_else(tmp_path):
    """Each run, relay and study gets the W&B flags with the sweep directory's name as its group (a relay and a study
    before --, to their tool); otherwise the commands are those of the same sweep untracked. A dry run needs no
    W&B login."""
    out = tmp_path / "paper-grid"
    grid = ["--paper", "minigrid", "--env-ids", "MiniGrid-DoorKey-6x6-v0", "--methods", "ppo", "ultho", "relay", "pbt",
            "--seeds", "1", "--points", "5:10", "--population", "2", "--ray-address", "10.0.0.1:6379", "--dry-run",
            "--out", str(out)]
    tracked = subprocess.run([sys.executable, os.path.join(REPO, TOOL), *grid, "--track", "--wandb-project-name",
                              "proj", "--wandb-entity", "team"], capture_output=True, text=True, cwd=REPO,
                             env=without_wandb_login(tmp_path))
    plain = run(TOOL, *grid)
    assert tracked.returncode == plain.returncode == 0, tracked.stderr
    flags = " --track --wandb-project-name proj --wandb-entity team --wandb-group paper-grid"
    commands = tracked.stdout.strip().splitlines()
    assert len(commands) == 4 and all(c.count(flags) == 1 for c in commands)
    assert all(c.index(flags) < c.index(" -- ") for c in commands if " -- " in c)  # the relay's and the study's
    assert [c.replace(flags, "") for c in commands] == plain.stdout.strip().splitlines()
    assert tracked.stderr == plain.stderr and not out.exists()


def test_tracked_sweep_mirrors_each_run_to_wandb_in_the_sweeps_group(tmp_path):
    out, wandb_dir = tmp_path / "tracked-sweep", tmp_path / "wandb"
    wandb_dir.mkdir()
    result = run(TOOL, "--methods", "ppo", "ultho", "--workers", "2", "--out", str(out), "--track",
                 "--wandb-project-name", "ultho-tests", *TINY,
                 env={"WANDB_MODE": "offline", "WANDB_DIR": str(wandb_dir), "WANDB_SILENT": "true"})
    assert result.returncode == 0, result.stdout + result.stderr
    runs = index(out)["runs"]
    assert [(r["method"], r["status"]) for r in runs] == [("ppo", "done"), ("ultho", "done")]
    offline = wandb_offline_runs(wandb_dir)
    ids = {r["name"]: (out / r["path"] / "wandb_id").read_text().strip() for r in runs}
    assert sorted(offline) == sorted(ids.values())
    for name, run_id in ids.items():
        [start] = [r.run for r in offline[run_id] if r.WhichOneof("record_type") == "run"]
        assert (start.display_name, start.project, start.run_group) == (name, "ultho-tests", "tracked-sweep")
        config = {item.key: json.loads(item.value_json) for item in start.config.update}
        assert config["env_id"] == "MiniGrid-Empty-5x5-v0" and config["total_timesteps"] == 512
        history = wandb_history(offline[run_id])
        assert [step for step, _ in history["charts/SPS"]] == [256, 512], name


def test_sweep_runs_a_pbt_study_and_indexes_it(tmp_path):
    out = tmp_path / "s"
    result = run(TOOL, "--methods", "pbt", "--population", "2", "--out", str(out), *TINY)
    assert result.returncode == 0, result.stdout + result.stderr
    [record] = index(out)["runs"]
    # A retried study means its first attempt failed: the sweep's log names why.
    assert (record["method"], record["status"], record["attempts"], record["c"]) == ("pbt", "done", 1, None), \
        result.stdout + result.stderr
    assert record["path"] == os.path.join("studies", "minigrid__MiniGrid-Empty-5x5-v0__pbt__s1")
    with open(out / record["path"] / "study.json") as f:
        study = json.load(f)
    assert (study["status"], study["method"], study["seed"]) == ("done", "pbt", 1)
    assert study["budget"]["total_steps"] == 2 * 512 and len(study["trials"]) == 2
    again = run(TOOL, "--methods", "pbt", "--population", "2", "--out", str(out), *TINY)
    assert again.returncode == 0 and "1 runs, 1 already done, 0 to run" in again.stdout


@pytest.fixture(scope="module")
def local_sweep(tmp_path_factory):
    out = tmp_path_factory.mktemp("local") / "s"
    result = run(TOOL, "--methods", "ppo", "ultho", "relay", "--out", str(out), "--workers", "2", *TINY)
    return out, result


def test_local_sweep_runs_every_grid_point_and_indexes_it(local_sweep):
    out, result = local_sweep
    assert result.returncode == 0, result.stdout + result.stderr
    record = index(out)
    assert record["format"] == 1
    assert record["grid"] == {"scripts": [SCRIPT], "env_ids": ["MiniGrid-Empty-5x5-v0"],
                              "methods": ["ppo", "ultho", "relay"], "c": [5.0], "window": [10],
                              "points": [[5.0, 10]], "variants": ["ucb:level:none"], "seeds": [1],
                              "population": 4,
                              "total_timesteps": 512, "grid_clusters": None, "extra_args": TINY[TINY.index("--") + 1:]}
    runs = {r["method"]: r for r in record["runs"]}
    assert len(record["runs"]) == 3 and all(set(r) == RUN_FIELDS for r in record["runs"])
    assert all(r["status"] == "done" and r["attempts"] == 1 and r["error"] is None for r in record["runs"])
    assert all(r["benchmark"] == "minigrid" and r["seed"] == 1 and r["script"] == SCRIPT for r in record["runs"])
    assert (runs["ppo"]["c"], runs["ppo"]["window"]) == (None, None)
    assert (runs["ultho"]["c"], runs["ultho"]["window"]) == (runs["relay"]["c"], runs["relay"]["window"]) == (5.0, 10)

    ppo, ultho = summary(str(out / runs["ppo"]["path"])), summary(str(out / runs["ultho"]["path"]))
    assert ppo["bandit"] is None and ppo["global_step"] == 512 and ppo["env_id"] == "MiniGrid-Empty-5x5-v0"
    assert (ultho["bandit"]["c"], ultho["bandit"]["window"], ultho["global_step"]) == (5.0, 10, 512)
    with open(out / runs["relay"]["path"] / "relay.json") as f:
        relay = json.load(f)
    # The relay reused the sweep's ULTHO run as its full run: two more runs, three in its budget.
    assert relay["status"] == "done" and relay["full_run"] == str(out / runs["ultho"]["path"])
    assert (relay["coi"], relay["noi"]) == ("learning_rate", "minibatch_size")
    assert relay["final_scores"]["full"] == ultho["final_score"] and relay["total_timesteps"] == 3 * 512
    assert not os.path.exists(out / runs["relay"]["path"] / "full")


def test_local_sweep_started_again_runs_nothing(local_sweep):
    out, _ = local_sweep
    before = {path: os.path.getmtime(path) for path in files_under(str(out)) if not path.endswith("sweep.json")}
    result = run(TOOL, "--methods", "ppo", "ultho", "relay", "--out", str(out), "--workers", "2", *TINY)
    assert result.returncode == 0, result.stderr
    assert "3 runs, 3 already done, 0 to run" in result.stdout
    assert {path: os.path.getmtime(path) for path in files_under(str(out)) if not path.endswith("sweep.json")} == before
    assert all(r["status"] == "done" and r["attempts"] == 1 for r in index(out)["runs"])


def test_sweep_on_a_new_machine_restores_the_exported_runs_and_reruns_only_the_rest(local_sweep, tmp_path):
    """The committed results of a study are its compact export; a fresh clone has no runs/ folder. With
    --done-from the exported runs count as done, so only the grid point that was never exported runs again."""
    out, _ = local_sweep
    exported = tmp_path / "data"
    result = run("ultho_report.py", str(out), "--out", str(tmp_path / "report"), "--no-per-run",
                 "--export-data", str(exported))
    assert result.returncode == 0, result.stderr
    ppo = next(r for r in index(out)["runs"] if r["method"] == "ppo")
    shutil.rmtree(exported / out.name / ppo["path"])  # finished after the last export
    fresh = tmp_path / out.name  # the same sweep directory name on the new machine, runs/ gone
    args = ["--methods", "ppo", "ultho", "relay", "--out", str(fresh), "--workers", "2", *TINY]
    result = run(TOOL, *args[:-len(TINY)], "--done-from", str(exported), *TINY)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f"2 finished runs restored from {exported}" in result.stdout
    assert "3 runs, 2 already done, 1 to run" in result.stdout
    record = {r["method"]: r for r in index(fresh)["runs"]}
    assert all(r["status"] == "done" for r in record.values())
    assert record["ppo"]["attempts"] == 1 and events(fresh / record["ppo"]["path"])  # ran here
    ultho_dir = fresh / record["ultho"]["path"]
    assert not events(ultho_dir) and (ultho_dir / "scalars.csv").exists()  # restored, not rerun
    assert summary(str(ultho_dir)) == summary(str(out / record["ultho"]["path"]))
    with open(fresh / record["relay"]["path"] / "relay.json") as f:
        assert json.load(f)["status"] == "done"
    assert not os.path.exists(fresh / "logs" / f"{record['ultho']['name']}.log")
    # Started again, nothing is restored twice and nothing runs.
    again = run(TOOL, *args[:-len(TINY)], "--done-from", str(exported), *TINY)
    assert "0 finished runs restored" in again.stdout and "3 runs, 3 already done, 0 to run" in again.stdout


def test_killed_sweep_restarted_finishes_only_what_is_missing(tmp_path):
    out = tmp_path / "s"
    # Eight iterations, a checkpoint after each: the second run is killed between checkpoints.
    args = [*TINY[:TINY.index("--total-timesteps")], "--total-timesteps", "2048", "--methods", "ultho",
            "--seeds", "1", "2", "--workers", "1", "--out", str(out), *TINY[TINY.index("--"):],
            "--checkpoint-every", "1"]
    process = subprocess.Popen([sys.executable, os.path.join(REPO, TOOL), *args], cwd=REPO, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, start_new_session=True)
    first = out / "runs" / "minigrid__MiniGrid-Empty-5x5-v0__ultho_c5.0_w10__s1"
    second = out / "runs" / "minigrid__MiniGrid-Empty-5x5-v0__ultho_c5.0_w10__s2"
    deadline = time.time() + 300
    while not (second / "checkpoint.pt").exists() and process.poll() is None and time.time() < deadline:
        time.sleep(0.01)
    os.killpg(process.pid, signal.SIGKILL)  # the sweep and the run it started, as a crash would
    process.wait()
    assert (first / "summary.json").exists() and not (second / "summary.json").exists(), "not killed in run 2"
    assert [r["status"] for r in index(out)["runs"]] == ["done", "running"]
    first_summary = (first / "summary.json").read_bytes()

    result = run(TOOL, *args)
    assert result.returncode == 0, result.stderr
    assert "2 runs, 1 already done, 1 to run" in result.stdout
    assert (first / "summary.json").read_bytes() == first_summary and len(events(first)) == 1
    assert len(events(second)) == 2  # resumed from its checkpoint, not started again
    assert summary(str(second))["global_step"] == 2048
    assert [(r["status"], r["attempts"]) for r in index(out)["runs"]] == [("done", 1), ("done", 1)]


def test_failing_run_is_retried_from_its_checkpoint_a_bounded_number_of_times(tmp_path):
    # The real script, made to die after its last checkpoint and before its summary (exit status 1): every
    # resume reaches the same point and fails again.
    crashing = tmp_path / SCRIPT
    crashing.write_text(
        "import sys\n"
        f"sys.path.insert(0, {REPO!r})\n"
        "import ppo_ultho_minigrid as script\n\n\n"
        "def crash(*args, **kwargs):\n"
        "    print('crashed before its summary', file=sys.stderr)\n"
        "    sys.exit(1)\n\n\n"
        "script.write_summary = crash\n"
        "script.main(script.parse_args())\n")
    out = tmp_path / "s"
    result = run(TOOL, "--scripts", str(crashing), "--env-ids", "MiniGrid-Empty-5x5-v0", "--methods", "ultho",
                 "--total-timesteps", "512", "--max-retries", "1", "--out", str(out), "--", "--num-envs", "4",
                 "--num-steps", "64", "--minibatch-size", "64", "--ultho-clusters", "learning_rate",
                 "--eval-episodes", "0")
    assert result.returncode == 1
    [record] = index(out)["runs"]
    assert record["status"] == "failed" and record["attempts"] == 2
    assert "failed 2 time(s), last exit status 1" in record["error"]
    with open(out / "logs" / f"{record['name']}.log") as f:
        log = f.read()
    assert log.count("crashed before its summary") == 2
    assert len(events(out / record["path"])) == 2  # the second attempt resumed from the checkpoint
    assert "1 failed: run the same command again" in result.stdout.splitlines()[-1]


def test_diverged_run_is_done_with_its_divergence_recorded_and_never_retried(tmp_path):
    # Iteration 2 takes the learning rate 1e38 (see test_minigrid.py): the loss is non-finite, the script exits
    # 1 with a summary that records where. Resuming would replay the same divergence, so the run is done.
    out = tmp_path / "s"
    args = [TOOL, "--scripts", SCRIPT, "--env-ids", "MiniGrid-Empty-5x5-v0", "--methods", "ppo", "ultho",
            "--total-timesteps", "2048", "--max-retries", "1", "--out", str(out), "--", "--num-envs", "4",
            "--num-steps", "64", "--minibatch-size", "64", "--ultho-clusters", "learning_rate=0.001,1e38",
            "--checkpoint-every", "1", "--eval-episodes", "2"]
    result = run(*args)
    assert result.returncode == 0, result.stdout + result.stderr
    runs = {r["method"]: r for r in index(out)["runs"]}
    assert [(r["status"], r["attempts"], r["error"]) for r in runs.values()] == [("done", 1, None)] * 2
    assert f"[sweep] done: {runs['ultho']['name']} (diverged at step 512)" in result.stdout
    diverged = summary(str(out / runs["ultho"]["path"]))
    assert diverged["diverged"] == {"what": "loss", "iteration": 2, "global_step": 512}
    assert diverged["final_score"] is not None and diverged["eval"]["episodes"] == 0
    ppo = summary(str(out / runs["ppo"]["path"]))  # plain PPO at its own lr, 1e-3, runs its budget
    assert ppo["diverged"] is None and ppo["global_step"] == 2048 and ppo["eval"]["episodes"] == 2
    with open(out / "logs" / f"{runs['ultho']['name']}.log") as f:
        log = f.read()
    assert log.count("non-finite loss at iteration 2") == 1 and len(events(out / runs["ultho"]["path"])) == 1
    before = os.path.getmtime(out / runs["ultho"]["path"] / "summary.json")
    assert run(*args).returncode == 0  # started again: nothing to do
    assert os.path.getmtime(out / runs["ultho"]["path"] / "summary.json") == before
    assert [r["attempts"] for r in index(out)["runs"]] == [1, 1]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def ray_head():
    """A real local Ray instance (2 CPUs, no dashboard), stopped by ending exactly the processes it started."""
    temp_dir = tempfile.mkdtemp(prefix="ray", dir="/tmp")  # short: Ray's socket paths must fit in 107 bytes
    port = free_port()
    ray = os.path.join(os.path.dirname(sys.executable), "ray")
    # Its workers run the scripts in its environment, where W&B is disabled for the tracked sweep's runs.
    process = subprocess.Popen([ray, "start", "--head", "--block", "--port", str(port), "--num-cpus", "2",
                                "--disable-usage-stats", "--include-dashboard=false", "--temp-dir", temp_dir,
                                "--ray-client-server-port", str(free_port())],
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True,
                               env={**os.environ, "WANDB_MODE": "disabled"})
    try:
        for line in process.stdout:
            if "Ray runtime started" in line:
                break
        else:
            pytest.fail("ray start --head did not start")
        yield f"127.0.0.1:{port}", temp_dir
    finally:
        for sig in (signal.SIGTERM, signal.SIGKILL):
            try:
                os.killpg(process.pid, sig)
            except ProcessLookupError:
                break
            time.sleep(2)
        process.wait()
        shutil.rmtree(temp_dir, ignore_errors=True)


def test_a_tracked_sweep_through_ray_passes_the_wandb_flags_to_its_tasks(ray_head, tmp_path):
    """The run, a Ray task on the instance's worker, was started with the flags: it kept a W&B id and its summary
    names the group. (W&B is disabled on the instance: its nodes, not the driver, decide how W&B logs.)"""
    address, _ = ray_head
    out = tmp_path / "ray-sweep"
    result = run(TOOL, "--methods", "ppo", "--ray-address", address, "--out", str(out), "--track", *TINY,
                 env={"WANDB_MODE": "disabled"})
    assert result.returncode == 0, result.stdout + result.stderr
    [record] = index(out)["runs"]
    assert record["status"] == "done" and (out / record["path"] / "wandb_id").exists()
    settings = summary(str(out / record["path"]))["settings"]
    assert (settings["track"], settings["wandb_project_name"], settings["wandb_group"]) == (True, "ultho", "ray-sweep")


def test_sweep_through_a_real_ray_instance(ray_head, tmp_path):
    address, temp_dir = ray_head
    out = tmp_path / "s"
    result = run(TOOL, "--methods", "ppo", "ultho", "--ray-address", address, "--cpus-per-run", "1",
                 "--out", str(out), *TINY)
    assert result.returncode == 0, result.stdout + result.stderr
    runs = index(out)["runs"]
    assert [(r["method"], r["status"], r["attempts"]) for r in runs] == [("ppo", "done", 1), ("ultho", "done", 1)]
    assert [summary(str(out / r["path"]))["global_step"] for r in runs] == [512, 512]
    # The runs were Ray tasks: the instance's workers ran them.
    logs = files_under(os.path.join(temp_dir, "session_latest", "logs"))
    assert any(os.path.basename(p).startswith("worker-") for p in logs), logs


BAD_INPUTS = [
    ([], "give --paper PRESET, or --scripts and --env-ids"),
    (["--paper", "minigrid", "--grid-clusters", "learning_rate"], "add grid to --methods"),
    (["--paper", "minigrid", "--methods", "grid", "--grid-clusters", "momentum"], "unknown cluster 'momentum'"),
    (["--paper", "minigrid", "--methods", "grid", "--", "--vf-coef", "2"], "--vf-coef after -- is set by the grid"),
    (["--paper", "mujoco"], "invalid choice: 'mujoco'"),
    (["--scripts", "ppo_ultho_nothing.py", "--env-ids", "X"], "script ppo_ultho_nothing.py: no such file"),
    (["--paper", "minigrid", "--seeds", "1", "1"], "--seeds 1 1: a value is given twice"),
    (["--paper", "minigrid", "--workers", "0"], "--workers must be positive, got 0"),
    (["--paper", "minigrid", "--methods", "hyperband"], "invalid choice: 'hyperband'"),
    (["--paper", "minigrid", "--methods", "pbt", "--population", "0"], "--population must be positive, got 0"),
    (["--paper", "minigrid", "--", "--seed", "3"], "--seed after -- is set by the grid"),
    (["--paper", "minigrid", "--points", "5"], "argument --points: '5' is not C:W (e.g. 5:10)"),
    (["--paper", "minigrid", "--points", "5:10", "--window", "50"], "--points gives the (c, W) pairs itself"),
    (["--paper", "minigrid", "--points", "5:10", "5.0:10"], "--points 5.0:10 5.0:10: a value is given twice"),
    (["--paper", "minigrid", "--points", "nan:10"], "--c must be finite and >= 0"),
    (["--paper", "minigrid", "--variants", "ts:delta:running"], "'ts:delta:running' is not STRATEGY:CREDIT:SCALE"),
    (["--paper", "minigrid", "--variants", "ts:level:none", "ts:level:none"], "--variants ts:level:none ts:level:none"),
    (["--paper", "minigrid", "--", "--ultho-scale", "running"], "--ultho-scale after -- is set by the grid"),
    (["--paper", "minigrid", "--", "--resume", "x"], "--resume after -- is set by the grid"),
    (["--paper", "minigrid", "--", "--init-from", "x"], "--init-from after -- is set by the grid"),
    (["--paper", "minigrid", "--done-from", "no/such/dir"], "--done-from no/such/dir: no such directory"),
    (["--paper", "minigrid", "--wandb-entity", "team"], "--wandb-entity and --wandb-group name where --track logs: "
                                                        "add --track"),
    (["--paper", "minigrid", "--wandb-group", "g"], "add --track"),
    (["--paper", "minigrid", "--track", "--wandb-project-name", ""], "--wandb-project-name '': W&B names are 1 to 128 "
                                                                    "characters without / \\ # ? % :"),
    (["--paper", "minigrid", "--track", "--wandb-entity", "t" * 129], "--wandb-entity 'ttt"),
    (["--paper", "minigrid", "--track", "--wandb-group", "a:b"], "--wandb-group 'a:b': W&B names"),
    (["--paper", "minigrid", "--", "--track"], "--track after --: put --track and the --wandb-* options before --"),
    (["--paper", "minigrid", "--track", "--", "--wandb-group=g"], "--wandb-group after --"),
]


@pytest.fixture(scope="module")
def bad_input_results(tmp_path_factory):
    base = tmp_path_factory.mktemp("bad")
    outs = [base / str(k) for k in range(len(BAD_INPUTS))]
    return list(zip(outs, run_concurrently(TOOL, [["--out", str(o), *a] for o, (a, _) in zip(outs, BAD_INPUTS)])))


@pytest.mark.parametrize("case", range(len(BAD_INPUTS)), ids=[" ".join(a) for a, _ in BAD_INPUTS])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(bad_input_results, case):
    out, result = bad_input_results[case]
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and BAD_INPUTS[case][1] in lines[0], result.stderr
    assert not out.exists()


def test_track_without_a_wandb_login_exits_2_before_any_run_starts(tmp_path):
    out = tmp_path / "s"
    result = subprocess.run([sys.executable, os.path.join(REPO, TOOL), "--methods", "ppo", "--out", str(out), "--track",
                             *TINY], capture_output=True, text=True, cwd=REPO, env=without_wandb_login(tmp_path))
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.strip().splitlines() == [
        f"{TOOL}: error: --track: no W&B login on this machine: run `wandb login`, or set WANDB_MODE=offline to log "
        "locally and `wandb sync` the runs later"]
    assert not out.exists()


def test_help_reads_well():
    result = run(TOOL, "--help")
    assert result.returncode == 0
    assert "python sweep.py --paper minigrid --dry-run" in result.stdout and "--ray-address" in result.stdout
    assert "--wandb-project-name NAME" in result.stdout and "(default: the name of the --out directory)" in \
        " ".join(result.stdout.split())

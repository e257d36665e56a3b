"""relay_ultho.py end to end on MiniGrid with tiny budgets: a relay killed in its COI run and started again."""

import argparse
import json
import os
import signal
import subprocess
import sys
import time

import pytest

from helpers import REPO, files_under, run, run_concurrently, summary, without_wandb_login
from relay_ultho import default_relay_dir
from ultho_runs import UsageError, add_tracking_options, flag_values, tracking_flags, without_flag

TOOL = "relay_ultho.py"
SCRIPT = "ppo_ultho_minigrid.py"
# 16 iterations of 4 envs x 64 steps: every Empty-5x5 episode (at most 100 steps) ends, and the 15 credited
# selections cannot split evenly between two clusters, so COI != NOI. Explicit values for one cluster check
# that the relay runs search the full run's values.
TINY = ["--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "4", "--num-steps", "64", "--total-timesteps", "4096",
        "--minibatch-size", "64", "--ultho-clusters", "learning_rate", "minibatch_size=32,64,128",
        "--checkpoint-every", "1", "--eval-episodes", "0", "--seed", "3"]



def summary_of(path) -> dict:
    with open(path) as f:
        return json.load(f)


def events(run_dir) -> list[str]:
    return [f for f in os.listdir(run_dir) if f.startswith("events.out.tfevents")]


@pytest.fixture(scope="module")
def interrupted_relay(tmp_path_factory):
    """A relay SIGKILLed (with its script) once the COI run has a checkpoint, then started again."""
    relay_dir = tmp_path_factory.mktemp("relay") / "r"
    command = [sys.executable, os.path.join(REPO, TOOL), SCRIPT, "--relay-dir", str(relay_dir), "--", *TINY, "--quiet"]
    process = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                               start_new_session=True)
    coi_checkpoint = relay_dir / "coi" / "checkpoint.pt"
    deadline = time.time() + 300
    while not coi_checkpoint.exists() and process.poll() is None and time.time() < deadline:
        time.sleep(0.01)
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    assert coi_checkpoint.exists() and not (relay_dir / "coi" / "summary.json").exists(), "not killed inside COI"
    full_summary_bytes = (relay_dir / "full" / "summary.json").read_bytes()
    interrupted_record = (relay_dir / "relay.json").read_text()
    # What a NOI run killed before its first checkpoint leaves: a directory with an event file and no checkpoint.
    (relay_dir / "noi").mkdir()
    (relay_dir / "noi" / "events.out.tfevents.0.killed").write_bytes(b"")
    result = run(TOOL, SCRIPT, "--relay-dir", str(relay_dir), "--", *TINY, "--quiet")
    return relay_dir, result, full_summary_bytes, interrupted_record


def test_restart_finishes_the_interrupted_run_and_repeats_nothing(interrupted_relay):
    relay_dir, result, full_summary_bytes, interrupted_record = interrupted_relay
    assert result.returncode == 0, result.stderr
    assert '"status": "running"' in interrupted_record and '"coi": "learning_rate"' in interrupted_record
    assert (relay_dir / "full" / "summary.json").read_bytes() == full_summary_bytes
    assert len(events(relay_dir / "full")) == 1
    assert f"resuming {os.path.join(REPO, SCRIPT)}" in result.stdout and "--resume" in result.stdout
    assert len(events(relay_dir / "coi")) == 2  # the killed process's and the resumed one's
    assert "events.out.tfevents.0.killed" not in os.listdir(relay_dir / "noi")
    assert "[relay] done" in result.stdout


def test_relay_json_is_taken_from_the_real_summaries(interrupted_relay):
    relay_dir = interrupted_relay[0]
    record = summary_of(relay_dir / "relay.json")
    full, coi, noi = (summary(str(relay_dir / name)) for name in ("full", "coi", "noi"))
    assert record["format"] == 1 and record["status"] == "done" and record["script"] == SCRIPT
    assert record["script_args"] == TINY + ["--quiet"]
    assert record["env_id"] == "MiniGrid-Empty-5x5-v0" and record["seed"] == 3
    assert (record["full_run"], record["coi_run"], record["noi_run"]) == ("full", "coi", "noi")
    assert (record["coi"], record["noi"]) == (full["bandit"]["coi"], full["bandit"]["noi"])
    assert record["coi"] != record["noi"]
    assert record["final_scores"] == {"full": full["final_score"], "coi": coi["final_score"], "noi": noi["final_score"]}
    winner = "coi" if coi["final_score"] >= noi["final_score"] else "noi"
    assert record["winner"] == winner and record["winner_run"] == winner
    assert record["final_score"] == max(coi["final_score"], noi["final_score"])
    assert record["total_timesteps"] == full["global_step"] + coi["global_step"] + noi["global_step"] == 3 * 4096


def test_relay_runs_search_one_cluster_each_with_the_full_runs_values_and_same_settings(interrupted_relay):
    relay_dir = interrupted_relay[0]
    full, coi, noi = (summary(str(relay_dir / name)) for name in ("full", "coi", "noi"))
    space = full["bandit"]["search_space"]
    assert space == {"learning_rate": [1e-3, 2.5e-3, 5e-3], "minibatch_size": [32, 64, 128]}
    for relay_run, cluster in ((coi, full["bandit"]["coi"]), (noi, full["bandit"]["noi"])):
        assert relay_run["bandit"]["search_space"] == {cluster: space[cluster]}
        assert relay_run["seed"] == full["seed"] and relay_run["env_id"] == full["env_id"]
        same = ("ultho_clusters", "run_name", "resume", "quiet")
        assert {k: v for k, v in relay_run["settings"].items() if k not in same} == \
               {k: v for k, v in full["settings"].items() if k not in same}


def test_a_finished_relay_started_again_starts_nothing(interrupted_relay):
    relay_dir = interrupted_relay[0]
    before = {path: os.path.getmtime(path) for path in files_under(str(relay_dir))}
    result = run(TOOL, SCRIPT, "--relay-dir", str(relay_dir), "--", *TINY, "--quiet")
    assert result.returncode == 0, result.stderr
    assert "starting" not in result.stdout and "resuming" not in result.stdout
    after = {path: os.path.getmtime(path) for path in files_under(str(relay_dir))}
    assert {p: t for p, t in after.items() if not p.endswith("relay.json")} == \
           {p: t for p, t in before.items() if not p.endswith("relay.json")}


def test_from_reuses_a_finished_full_run(interrupted_relay, tmp_path):
    """--from takes the full run as it is; a one-cluster run (the COI run) cannot seed a relay."""
    relay_dir = interrupted_relay[0]
    result = run(TOOL, SCRIPT, "--from", str(relay_dir / "coi"), "--relay-dir", str(tmp_path / "r"), "--", *TINY)
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [
        f"{TOOL}: error: --from {relay_dir / 'coi'} searched one cluster (learning_rate): Relay-ULTHO needs a full "
        "run over at least two clusters, since its COI and NOI would coincide"]
    assert not (tmp_path / "r").exists()


def test_full_run_without_a_credited_selection_is_reported(tmp_path):
    # One iteration: the only selection is never credited, so the full run says nothing about its clusters.
    one_iteration = without_flag(TINY, "--total-timesteps") + ["--total-timesteps", "256", "--quiet"]
    result = run(TOOL, SCRIPT, "--relay-dir", str(tmp_path / "r"), "--quiet", "--", *one_iteration)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "credited no selection (selections {'learning_rate': 0, 'minibatch_size': 0})" \
        in lines[0], result.stderr
    assert not (tmp_path / "r" / "coi").exists()


def test_clusters_selected_equally_often_still_relay(tmp_path):
    """A full tie (the bandit rotated its clusters): COI = the first cluster, NOI = the second, and both run."""
    # 17 iterations: 16 credited selections; at c=5 the bonus outweighs Empty-5x5's values in [0, 1], so the
    # bandit alternates between its two clusters and each is chosen 8 times.
    tied = without_flag(TINY, "--total-timesteps") + ["--total-timesteps", str(17 * 256), "--ultho-c", "5"]
    relay_dir = tmp_path / "r"
    result = run(TOOL, SCRIPT, "--relay-dir", str(relay_dir), "--quiet", "--", *tied)
    assert result.returncode == 0, result.stderr
    full = summary(str(relay_dir / "full"))
    assert full["bandit"]["selections"] == {"learning_rate": 8, "minibatch_size": 8}
    assert (full["bandit"]["coi"], full["bandit"]["noi"]) == ("learning_rate", "minibatch_size")
    record = summary_of(relay_dir / "relay.json")
    assert (record["coi"], record["noi"], record["status"]) == ("learning_rate", "minibatch_size", "done")
    assert summary(str(relay_dir / "noi"))["bandit"]["search_space"] == {"minibatch_size": [32, 64, 128]}


def test_a_run_that_diverged_is_done_and_loses_to_one_that_did_not(tmp_path):
    # The learning rate 1e38 makes the loss non-finite in the iteration after it is chosen: the full run chooses
    # it at iteration 3 (learning_rate, then the untried minibatch_size, credited one each: COI learning_rate,
    # NOI minibatch_size), the COI run at iteration 2. Both are done after one attempt, with their summaries
    # saying where; the COI run scored more before it diverged, yet the NOI run, which finished, wins.
    relay_dir = tmp_path / "r"
    args = ["--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "4", "--num-steps", "64", "--total-timesteps", "2048",
            "--minibatch-size", "64", "--ultho-clusters", "learning_rate=0.001,1e38", "minibatch_size=32,64,128",
            "--checkpoint-every", "1", "--eval-episodes", "0", "--seed", "3"]
    result = run(TOOL, SCRIPT, "--relay-dir", str(relay_dir), "--", *args)
    assert result.returncode == 0, result.stdout + result.stderr
    record = summary_of(relay_dir / "relay.json")
    full, coi, noi = (summary(str(relay_dir / role)) for role in ("full", "coi", "noi"))
    assert full["diverged"] == {"what": "loss", "iteration": 3, "global_step": 768}
    assert coi["diverged"] == {"what": "loss", "iteration": 2, "global_step": 512} and noi["diverged"] is None
    assert (record["status"], record["coi"], record["noi"]) == ("done", "learning_rate", "minibatch_size")
    assert record["final_scores"] == {"full": full["final_score"], "coi": coi["final_score"],
                                      "noi": noi["final_score"]}
    assert coi["final_score"] > noi["final_score"]
    assert (record["winner"], record["final_score"]) == ("noi", noi["final_score"])
    assert record["total_timesteps"] == 768 + 512 + 2048
    assert result.stdout.count("starting ") == 3 and "resuming " not in result.stdout
    assert f"scored {coi['final_score']} (diverged at step 512)" in result.stdout


def test_a_tracked_relay_starts_its_three_runs_with_the_wandb_flags_in_one_group(tmp_path):
    # Two iterations: one credited selection is enough for a COI and a NOI. W&B is disabled: what is checked is
    # the command lines and what the runs made of them (tests/test_sweep.py reads back a tracked run's W&B records).
    relay_dir = tmp_path / "doorkey-relay"
    two_iterations = without_flag(TINY, "--total-timesteps") + ["--total-timesteps", "512", "--quiet"]
    result = run(TOOL, SCRIPT, "--relay-dir", f"{relay_dir}{os.sep}", "--track", "--wandb-project-name", "proj",
                 "--wandb-entity", "team", "--", *two_iterations, env={"WANDB_MODE": "disabled"})
    assert result.returncode == 0, result.stdout + result.stderr
    flags = " --track --wandb-project-name proj --wandb-entity team --wandb-group doorkey-relay "
    started = [line for line in result.stdout.splitlines() if line.startswith("starting ")]
    assert len(started) == 3 and all(line.count(flags) == 1 for line in started), started
    for role in ("full", "coi", "noi"):
        settings = summary(str(relay_dir / role))["settings"]
        assert (settings["track"], settings["wandb_group"], settings["wandb_entity"]) == (True, "doorkey-relay", "team")
        assert (relay_dir / role / "wandb_id").exists()
    assert summary_of(relay_dir / "relay.json")["script_args"] == two_iterations  # the flags are not the relay's


def tracking_options(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    add_tracking_options(parser, "the runs", "the folder's name")
    return parser.parse_args(argv)


def test_tracking_flags_are_the_scripts_with_the_group_given_or_else_the_folders(monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    assert tracking_flags(tracking_options(), [], "folder") == []
    assert tracking_flags(tracking_options("--track"), [], "folder") == [
        "--track", "--wandb-project-name", "ultho", "--wandb-group", "folder"]
    assert tracking_flags(tracking_options("--track", "--wandb-entity", "team", "--wandb-group", "sweep"), [],
                          "folder") == ["--track", "--wandb-project-name", "ultho", "--wandb-entity", "team",
                                        "--wandb-group", "sweep"]
    assert tracking_flags(tracking_options("--track", "--wandb-group", "g" * 128), [], "f")[-1] == "g" * 128


@pytest.mark.parametrize("name", ["", "g" * 129, "a/b", "a\\b", "a#b", "a?b", "a%b", "a:b"])
def test_tracking_flags_refuse_a_name_wandb_refuses(monkeypatch, name):
    monkeypatch.setenv("WANDB_MODE", "offline")
    for flag in ("--wandb-project-name", "--wandb-entity", "--wandb-group"):
        with pytest.raises(UsageError, match=f"^{flag} .*: W&B names are 1 to 128 characters"):
            tracking_flags(tracking_options("--track", flag, name), [], "folder")
    with pytest.raises(UsageError, match="W&B group is by default the folder's name.*give --wandb-group NAME$"):
        tracking_flags(tracking_options("--track"), [], name)


def test_track_without_a_wandb_login_exits_2_before_any_run_starts(tmp_path):
    relay_dir = tmp_path / "r"
    result = subprocess.run([sys.executable, os.path.join(REPO, TOOL), SCRIPT, "--relay-dir", str(relay_dir), "--track",
                             "--", *TINY], capture_output=True, text=True, cwd=REPO, env=without_wandb_login(tmp_path))
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.strip().splitlines() == [
        f"{TOOL}: error: --track: no W&B login on this machine: run `wandb login`, or set WANDB_MODE=offline to log "
        "locally and `wandb sync` the runs later"]
    assert not relay_dir.exists()


BAD_INPUTS = [
    ([SCRIPT, "--", "--no-ultho"], "--no-ultho is set by the tool itself"),
    ([SCRIPT, "--", "--run-name", "x"], "--run-name is set by the tool itself"),
    ([SCRIPT, "--", "--runs-dir=elsewhere"], "--runs-dir is set by the tool itself"),
    ([SCRIPT, "--", "--resume", "runs/x"], "--resume is set by the tool itself"),
    ([SCRIPT, "--", "--init-from", "runs/x"], "--init-from is set by the tool itself"),
    ([SCRIPT, "--", "--ultho-clusters", "vf_coef"],
     "--ultho-clusters vf_coef: Relay-ULTHO needs at least two clusters"),
    (["ppo_ultho_nothing.py"], "script ppo_ultho_nothing.py: no such file"),
    ([SCRIPT, "--from", "/no/such/run"], "--from /no/such/run: no summary.json there"),
    ([SCRIPT, "--max-retries", "-1"], "--max-retries must be >= 0, got -1"),
    ([SCRIPT, "--bogus"], "unrecognized arguments: --bogus"),
    ([SCRIPT, "--", "--env-id", "CartPole-v1"], "CartPole-v1"),  # the script's own check, through the relay
    ([], "the following arguments are required: script"),
    ([SCRIPT, "--wandb-entity", "team"], "--wandb-entity and --wandb-group name where --track logs: add --track"),
    ([SCRIPT, "--wandb-group", "g"], "add --track"),
    ([SCRIPT, "--track", "--wandb-project-name", "a/b"], "--wandb-project-name 'a/b': W&B names are 1 to 128"),
    ([SCRIPT, "--", "--track"], "--track after --: put --track and the --wandb-* options before --"),
    ([SCRIPT, "--track", "--", "--wandb-entity", "team"], "--wandb-entity after --"),
]


@pytest.fixture(scope="module")
def bad_input_results(tmp_path_factory):
    base = tmp_path_factory.mktemp("bad")
    dirs = [base / str(k) for k in range(len(BAD_INPUTS))]
    return list(zip(dirs, run_concurrently(TOOL, [
        args[:1] + ["--relay-dir", str(d)] + args[1:] if args else args for d, (args, _) in zip(dirs, BAD_INPUTS)])))


@pytest.mark.parametrize("case", range(len(BAD_INPUTS)), ids=[" ".join(a) for a, _ in BAD_INPUTS])
def test_bad_input_exits_2_with_one_line_and_writes_nothing(bad_input_results, case):
    relay_dir, result = bad_input_results[case]
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and BAD_INPUTS[case][1] in lines[0], result.stderr
    assert not relay_dir.exists()


def test_a_relay_directory_of_other_arguments_is_refused(interrupted_relay):
    relay_dir = interrupted_relay[0]
    result = run(TOOL, SCRIPT, "--relay-dir", str(relay_dir), "--", *TINY[:-1], "4")
    assert result.returncode == 2
    assert len(result.stderr.strip().splitlines()) == 1 and "holds a relay of other arguments" in result.stderr


def test_argument_helpers_and_default_directory():
    args = ["--env-id", "A", "--ultho-clusters", "x", "y=1,2", "--seed=4", "--ultho-c", "-1"]
    assert flag_values(args, "--ultho-clusters") == ["x", "y=1,2"]
    assert flag_values(args, "--seed") == ["4"] and flag_values(args, "--cuda") is None
    assert without_flag(args, "--ultho-clusters") == ["--env-id", "A", "--seed=4", "--ultho-c", "-1"]
    same = default_relay_dir(SCRIPT, args, None)
    assert same == default_relay_dir(SCRIPT, list(args), None)
    assert same.startswith(os.path.join("runs", "relay__ppo_ultho_minigrid__A__4__"))
    assert default_relay_dir(SCRIPT, args + ["--gamma", "0.9"], None) != same


def test_help_reads_well():
    result = run(TOOL, "--help")
    assert result.returncode == 0
    assert "Relay-ULTHO (Algorithm 2)" in result.stdout
    assert "python relay_ultho.py ppo_ultho_procgen.py" in result.stdout

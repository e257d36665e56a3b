"""hpo_baselines.py end to end: PBT, PB2 and random search through a real local Ray instance, tiny MiniGrid runs."""

import json
import os
import signal
import subprocess
import sys
import time

import pytest
import torch

import hpo_baselines
from helpers import REPO, files_under, run, run_concurrently, run_ok, scalars, summary, without_wandb_login
from hpo_study import FLAGS, SCRIPT, SCRIPT_ARGS, SPACE, STEP, STUDY_FIELDS, TOOL, study


def read(path) -> dict:
    with open(path) as f:
        return json.load(f)


def tune_checkpoint(study_dir, trial: str, step: int) -> str:
    """The checkpoint directory that Tune kept for ``trial`` at ``step``."""
    for directory, _, files in os.walk(os.path.join(study_dir, "tune")):
        if "hpo_checkpoint.json" in files:
            record = read(os.path.join(directory, "hpo_checkpoint.json"))
            if (record["trial"], record["step"]) == (trial, step):
                return directory
    raise AssertionError(f"no Tune checkpoint of {trial} at step {step}")


def weights(checkpoint_dir) -> dict:
    return torch.load(os.path.join(checkpoint_dir, "checkpoint.pt"), weights_only=False)["agent"]


def assert_trials_followed_their_records(study_dir, record: dict) -> None:
    """Each trial's run directory is a whole run of the budget whose hparams/* are its recorded schedule."""
    final = record["budget"]["steps_per_trial"]
    for trial in record["trials"]:
        run_dir = os.path.join(study_dir, trial["run_dir"])
        assert trial["complete"] and summary(run_dir)["global_step"] == final
        assert summary(run_dir)["final_score"] == trial["final_score"] == trial["segments"][-1]["score"]
        series = scalars(run_dir)
        for name in SPACE:
            expected = [(step, float(segment["settings"][name])) for segment in trial["segments"]
                        for step in range(segment["start_step"] + STEP, segment["end_step"] + 1, STEP)]
            assert [(s, pytest.approx(v)) for s, v in expected] == series[f"hparams/{name}"], (trial["name"], name)
        # The optimizer's own learning rate followed the schedule too.
        learning_rates = [v for _, v in series["hparams/learning_rate"]]
        assert [v for _, v in series["charts/learning_rate"]] == pytest.approx(learning_rates)


def assert_scores_recorded(record: dict) -> None:
    finals = {t["name"]: t["final_score"] for t in record["trials"]}
    assert record["best_trial"] == max(finals, key=finals.get) and record["best_final_score"] == max(finals.values())
    every = [(s["score"], t["name"], s["end_step"]) for t in record["trials"] for s in t["segments"]]
    best_seen = max(every)
    assert record["max_observed_score"] == {"score": best_seen[0], "trial": best_seen[1], "step": best_seen[2]}
    assert record["max_observed_score"]["score"] >= record["best_final_score"]


def test_pbt_study_records_budget_exploits_and_best_trial(pbt_study):
    study_dir, stdout = pbt_study
    record = read(study_dir / "study.json")
    assert set(record) == STUDY_FIELDS and record["status"] == "done" and record["errors"] == []
    assert (record["method"], record["population"], record["seed"]) == ("pbt", 3, 1)
    assert record["search_space"] == SPACE
    # Synchronous PBT: every trial ran the whole budget, so the population's is 3 x 1,024 steps.
    assert record["budget"] == {"steps_per_trial": 1024, "trials": 3, "total_steps": 3 * 1024, "interval": 512}
    assert [t["name"] for t in record["trials"]] == ["trial_0", "trial_1", "trial_2"]
    assert [t["seed"] for t in record["trials"]] == [1000, 1001, 1002]
    assert all(t["steps_run"] == 1024 for t in record["trials"])
    # A population of three ranks one trial at the bottom at the one perturbation (step 512): it copies the top.
    assert len(record["exploits"]) >= 1
    for exploit in record["exploits"]:
        assert exploit["step"] == 512 and exploit["trial"] != exploit["source_trial"]
        trial = next(t for t in record["trials"] if t["name"] == exploit["trial"])
        assert exploit["old_settings"] == trial["segments"][0]["settings"]
        assert exploit["new_settings"] == trial["segments"][1]["settings"]
        source = next(t for t in record["trials"] if t["name"] == exploit["source_trial"])
        assert exploit["source_settings"] == source["segments"][0]["settings"]
        # PBT's explore: each cluster is the source's value, a neighbour of it, or resampled, never off the list.
        assert all(exploit["new_settings"][name] in SPACE[name] for name in SPACE)
    assert_scores_recorded(record)
    assert_trials_followed_their_records(study_dir, record)
    # The best trial's schedule follows its network back through the exploits to step 0.
    best = next(t for t in record["trials"] if t["name"] == record["best_trial"])
    schedule = record["best_settings_schedule"]
    assert [(s["start_step"], s["end_step"]) for s in schedule] == [(0, 512), (512, 1024)]
    assert schedule[1]["settings"] == best["segments"][1]["settings"]
    first = best["segments"][1]["started_from"]["trial"]
    assert schedule[0]["trial"] == first
    assert "[hpo] done: 3 trials, 3,072 steps in all" in stdout


def test_pbt_exploit_starts_from_the_source_checkpoint_with_the_new_settings(pbt_study, tmp_path):
    """Right after an exploit the trial's network, optimizer and environments are the source's, and the new
    settings (not the old ones) are in force, the optimizer's learning rate included."""
    study_dir, _ = pbt_study
    record = read(study_dir / "study.json")
    exploit = record["exploits"][0]
    trial = next(t for t in record["trials"] if t["name"] == exploit["trial"])
    source = tune_checkpoint(study_dir, exploit["source_trial"], 512)
    after = tune_checkpoint(study_dir, exploit["trial"], 1024)

    def redo(settings: dict, name: str) -> dict:
        flags = [token for key, value in settings.items() for token in (FLAGS[key], str(value))]
        run_ok(SCRIPT, *SCRIPT_ARGS, *flags, "--no-ultho", "--seed", str(trial["seed"]), "--total-timesteps", "1024",
               "--init-from", source, "--runs-dir", str(tmp_path), "--run-name", name, "--quiet")
        return weights(tmp_path / name)

    # Training is deterministic on the CPU: the trial's segment is the script run from the source's checkpoint
    # with the new settings, bit for bit.
    redone = redo(exploit["new_settings"], "new")
    assert all(torch.equal(redone[k], weights(after)[k]) for k in redone)
    if exploit["old_settings"] != exploit["new_settings"]:
        with_old = redo(exploit["old_settings"], "old")
        assert not all(torch.equal(with_old[k], weights(after)[k]) for k in with_old)
    # The trial's own TensorBoard events after the exploit: the new settings, the optimizer's learning rate too.
    series = scalars(os.path.join(study_dir, trial["run_dir"]))
    for name in SPACE:
        assert [v for s, v in series[f"hparams/{name}"] if s > 512] == \
               pytest.approx([exploit["new_settings"][name]] * 2), name
    assert [v for s, v in series["charts/learning_rate"] if s > 512] == \
           pytest.approx([exploit["new_settings"]["learning_rate"]] * 2)
    optimizer = torch.load(os.path.join(after, "checkpoint.pt"), weights_only=False)["optimizer"]
    assert optimizer["param_groups"][0]["lr"] == exploit["new_settings"]["learning_rate"]


def test_pb2_and_random_search_run_to_completion(tmp_path):
    pb2 = study(tmp_path / "pb2", "--method", "pb2", "--population", "3")
    assert pb2.returncode == 0, pb2.stdout + pb2.stderr
    record = read(tmp_path / "pb2" / "study.json")
    assert set(record) == STUDY_FIELDS
    assert (record["status"], record["method"], record["population"]) == ("done", "pb2", 3)
    assert record["budget"] == {"steps_per_trial": 1024, "trials": 3, "total_steps": 3 * 1024, "interval": 512}
    assert len(record["exploits"]) >= 1
    for trial in record["trials"]:
        for segment in trial["segments"]:
            settings = segment["settings"]
            # PB2 searches each cluster's range; integers are rounded to divisors of the 256-step rollout.
            assert settings["minibatch_size"] in (32, 64, 128)
            assert 1e-3 <= settings["learning_rate"] <= 5e-3 and 0.25 <= settings["vf_coef"] <= 1.0
    assert_scores_recorded(record)
    assert_trials_followed_their_records(tmp_path / "pb2", record)

    # Without --ray-address the study runs on a Ray instance of its own, even where RAY_ADDRESS names a cluster
    # (here one that is not there), which ray.init() with no address would join.
    rs = study(tmp_path / "random", "--method", "random", "--samples", "2", env={"RAY_ADDRESS": "127.0.0.1:1"})
    assert rs.returncode == 0, rs.stdout + rs.stderr
    record = read(tmp_path / "random" / "study.json")
    assert set(record) == STUDY_FIELDS
    assert (record["status"], record["method"], record["samples"]) == ("done", "random", 2)
    assert record["budget"] == {"steps_per_trial": 1024, "trials": 2, "total_steps": 2 * 1024, "interval": 512}
    assert record["exploits"] == []
    for trial in record["trials"]:
        assert len({json.dumps(s["settings"]) for s in trial["segments"]}) == 1  # one setting for the whole run
        assert all(trial["settings"][name] in SPACE[name] for name in SPACE)
    assert_scores_recorded(record)
    assert_trials_followed_their_records(tmp_path / "random", record)
    assert record["best_settings_schedule"][0]["settings"] == \
           next(t for t in record["trials"] if t["name"] == record["best_trial"])["settings"]


def test_killed_study_started_again_finishes_without_rerunning_finished_trials(tmp_path):
    study_dir = tmp_path / "s"
    # One trial at a time, three segments each: killed once trial_1 has reported its first segment.
    args = [TOOL, SCRIPT, "--method", "random", "--samples", "2", "--interval", str(2 * STEP), "--study-dir",
            str(study_dir), "--num-cpus", "1", "--", *SCRIPT_ARGS, "--total-timesteps", str(6 * STEP)]
    process = subprocess.Popen([sys.executable, *args], cwd=REPO, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, start_new_session=True)
    second = study_dir / "trials" / "trial_1" / "hpo_trial.json"
    deadline = time.time() + 600
    while not second.exists() and process.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    os.killpg(process.pid, signal.SIGKILL)  # the driver, its Ray instance and the running segment, as a crash
    process.wait()
    first = study_dir / "trials" / "trial_0"
    assert read(first / "hpo_trial.json")["complete"] and not read(second)["complete"], "not killed in trial_1"
    finished = {path: os.path.getmtime(path) for path in files_under(str(first))}
    assert read(study_dir / "study.json")["status"] == "running"

    result = run(*args)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "continuing the study" in result.stdout
    assert {path: os.path.getmtime(path) for path in files_under(str(first))} == finished
    record = read(study_dir / "study.json")
    assert record["status"] == "done" and [t["complete"] for t in record["trials"]] == [True, True]
    # trial_1 went on from its last reported checkpoint: each segment ran once, the budget is exact.
    assert [(s["start_step"], s["end_step"]) for s in record["trials"][1]["segments"]] == [(0, 512), (512, 1024),
                                                                                            (1024, 1536)]
    assert record["budget"]["total_steps"] == 2 * 1536
    assert_trials_followed_their_records(study_dir, record)
    again = run(*args)
    assert again.returncode == 0 and "is done; nothing to run" in again.stdout


def niceness_of_descendants_running(root_pid: int, script: str) -> dict[int, int]:
    """pid -> niceness of every process under ``root_pid`` (its children, theirs, ...) whose command names ``script``,
    read from /proc (a process may end between the reads: it is then left out)."""
    parents, niceness = {}, {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    fields = f.read().rsplit(")", 1)[1].split()  # after the command name, which may hold spaces
                with open(f"/proc/{entry}/cmdline", "rb") as f:
                    command = f.read().decode(errors="replace")
            except OSError:
                continue
            parents[int(entry)] = int(fields[1])
            if script in command:
                niceness[int(entry)] = int(fields[16])

    def descends(pid: int) -> bool:
        while pid > 1:
            pid = parents.get(pid, 0)
            if pid == root_pid:
                return True
        return False

    return {pid: nice for pid, nice in niceness.items() if descends(pid)}


def test_trials_train_at_the_niceness_the_tool_started_with_not_rays(tmp_path):
    """Ray starts its workers at niceness 15; beside any busy process a trial's training then got a few percent of a
    core. On the study's own Ray instance every segment's training process runs at the tool's niceness."""
    args = [TOOL, SCRIPT, "--method", "random", "--samples", "1", "--interval", str(2 * STEP), "--study-dir",
            str(tmp_path / "s"), "--num-cpus", "1", "--", *SCRIPT_ARGS, "--total-timesteps", str(4 * STEP)]
    process = subprocess.Popen([sys.executable, *args], cwd=REPO, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL)
    seen: dict[int, int] = {}
    deadline = time.time() + 600
    while process.poll() is None and time.time() < deadline:
        seen.update(niceness_of_descendants_running(process.pid, SCRIPT))
        time.sleep(0.05)
    assert process.wait(timeout=60) == 0
    assert len(seen) >= 2, f"saw {len(seen)} of the two segments' training processes"
    assert set(seen.values()) == {os.nice(0)}


def test_killed_pbt_study_started_again_goes_on_in_step(tmp_path):
    """After a restart Tune's scheduler is new while the trials are an interval or more into the budget: the
    population must still be synchronized at every later interval, and the exploit made before the kill kept."""
    study_dir = tmp_path / "s"
    args = [TOOL, SCRIPT, "--method", "pbt", "--population", "2", "--interval", str(2 * STEP), "--study-dir",
            str(study_dir), "--num-cpus", "2", "--", *SCRIPT_ARGS, "--total-timesteps", str(6 * STEP)]
    process = subprocess.Popen([sys.executable, *args], cwd=REPO, stdout=subprocess.DEVNULL,
                               stderr=subprocess.DEVNULL, start_new_session=True)
    records = [study_dir / "trials" / f"trial_{k}" / "hpo_trial.json" for k in (0, 1)]
    deadline = time.time() + 600
    while not all(r.exists() for r in records) and process.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    time.sleep(3)  # into the second interval
    os.killpg(process.pid, signal.SIGKILL)
    process.wait()
    assert not any(read(r)["complete"] for r in records), "killed too late"

    result = run(*args, timeout=900)
    assert result.returncode == 0, result.stdout + result.stderr
    record = read(study_dir / "study.json")
    assert record["status"] == "done" and record["budget"]["total_steps"] == 2 * 1536
    for trial in record["trials"]:
        assert [(s["start_step"], s["end_step"]) for s in trial["segments"]] == [(0, 512), (512, 1024), (1024, 1536)]
    # The perturbation after the restart (step 1024) has one trial copying the other; the one at 512 is kept
    # when Tune had saved it before the kill, else that trial went on from its own checkpoint.
    steps = sorted(e["step"] for e in record["exploits"])
    assert steps in ([1024], [512, 1024]), steps
    assert_trials_followed_their_records(study_dir, record)


def test_a_diverged_trial_keeps_its_last_score_and_the_population_in_step(tmp_path):
    # The study's seed gives trial_1 the learning rate 1e38, so its loss is non-finite in its first iteration
    # (128-step rollouts: episodes have ended by then, and score it); trial_0 trains normally. One CPU, so the
    # trials take turns and the healthy one waits at each synchronization point for the diverged one: had the
    # diverged trial ended early, the synchronous PBT would have waited for it for good.
    study_dir = tmp_path / "s"
    result = run(TOOL, SCRIPT, "--method", "pbt", "--population", "2", "--seed", "1", "--interval", "1024",
                 "--study-dir", str(study_dir), "--num-cpus", "1", "--", "--env-id", "MiniGrid-Empty-5x5-v0",
                 "--num-envs", "4", "--num-steps", "128", "--minibatch-size", "128", "--ultho-clusters",
                 "learning_rate=0.001,1e38", "minibatch_size=64,128", "--eval-episodes", "2",
                 "--total-timesteps", "3072", timeout=900)
    assert result.returncode == 0, result.stdout + result.stderr
    record = read(study_dir / "study.json")
    healthy, diverged = record["trials"]
    assert (record["status"], record["errors"], record["exploits"]) == ("done", [], [])
    assert healthy["settings"]["learning_rate"] == 0.001 and diverged["settings"]["learning_rate"] == 1e38
    run_summary = summary(str(study_dir / diverged["run_dir"]))
    assert run_summary["diverged"] == diverged["diverged"] == {"what": "loss", "iteration": 1, "global_step": 512}
    # Its one segment ran to the divergence; it then reported at every interval without training.
    [segment] = diverged["segments"]
    assert (segment["start_step"], segment["end_step"], segment["diverged"]) == (0, 1024, diverged["diverged"])
    assert diverged["complete"] and diverged["steps_run"] == 512
    assert diverged["final_score"] == segment["score"] == run_summary["final_score"] is not None
    assert result.stdout.count("diverged, trains no more") == 3
    assert healthy["diverged"] is None and healthy["complete"] and healthy["steps_run"] == 3072
    assert [s["diverged"] for s in healthy["segments"]] == [None] * 3
    assert record["budget"]["total_steps"] == 3072 + 512
    # Never the best, whatever it scored before it diverged.
    assert record["best_trial"] == "trial_0" and record["best_final_score"] == healthy["final_score"]



def segment_commands(study_dir, *tool_args: str) -> tuple[list[str], list[str]]:
    """The first and the last segment command of trial_1 in a two-segment study of these options (nothing runs)."""
    args, script_args = hpo_baselines.parse_args([SCRIPT, "--method", "pbt", "--population", "2", "--interval",
                                                  str(2 * STEP), "--study-dir", str(study_dir), *tool_args, "--",
                                                  *SCRIPT_ARGS, "--total-timesteps", str(4 * STEP)])
    plan = hpo_baselines.checked_plan(args, script_args, str(study_dir))
    settings = plan.settings_of({"learning_rate": 1e-3, "minibatch_size": 64, "vf_coef": 0.5})
    return (plan.segment_command("trial_1", 1001, 2 * STEP, settings, None),
            plan.segment_command("trial_1", 1001, 4 * STEP, settings, str(study_dir / "trials" / "trial_1")))


def test_track_gives_every_segment_the_wandb_flags_with_the_study_as_its_group(tmp_path, monkeypatch):
    """A trial is one W&B run across its segments (the script keeps its W&B id in the trial's run directory); all
    trials of a study share the group: the study directory's name, or --wandb-group (sweep.py gives its own)."""
    monkeypatch.setenv("WANDB_MODE", "offline")
    study_dir = tmp_path / "pbt-doorkey"
    plain = segment_commands(study_dir)
    tracked = segment_commands(study_dir, "--track", "--wandb-project-name", "proj", "--wandb-entity", "team")
    flags = ["--track", "--wandb-project-name", "proj", "--wandb-entity", "team", "--wandb-group", "pbt-doorkey"]
    for without, with_ in zip(plain, tracked):
        assert with_ == without + flags and without[-1] == "--quiet"
    grouped = segment_commands(study_dir, "--track", "--wandb-group", "my-sweep")
    assert all(c[-6:] == ["--quiet", "--track", "--wandb-project-name", "ultho", "--wandb-group", "my-sweep"]
               for c in grouped)
    assert not study_dir.exists()


def test_track_without_a_wandb_login_exits_2_before_ray_starts(tmp_path):
    study_dir = tmp_path / "study"
    result = subprocess.run([sys.executable, os.path.join(REPO, TOOL), SCRIPT, "--method", "pbt", "--population", "2",
                             "--study-dir", str(study_dir), "--track", "--", *SCRIPT_ARGS],
                            capture_output=True, text=True, cwd=REPO, env=without_wandb_login(tmp_path))
    assert result.returncode == 2 and result.stdout == ""
    assert result.stderr.strip().splitlines() == [
        f"{TOOL}: error: --track: no W&B login on this machine: run `wandb login`, or set WANDB_MODE=offline to log "
        "locally and `wandb sync` the runs later"]
    assert not study_dir.exists()


BAD_INPUTS = [
    (["--method", "hyperband"], "--method hyperband: not one of pbt, pb2, random"),
    (["--method", "pbt", "--population", "1"], "--population must be >= 2 for pbt"),
    (["--method", "pb2"], "--population must be >= 2 for pb2 (a trial exploits another), got None"),
    (["--method", "random", "--samples", "0"], "--samples must be >= 1 for random search, got 0"),
    (["--method", "random", "--samples", "2", "--population", "2"], "--population is for pbt and pb2"),
    (["--method", "pbt", "--population", "4", "--interval", "300"],
     "--interval 300 is not a whole number of iterations (one iteration is 256 steps"),
    (["--method", "pbt", "--population", "4", "--", "--num-envs", "0"],
     "ppo_ultho_minigrid: --num-envs must be positive, got 0"),
    (["--method", "pbt", "--population", "4", "--", "--minibatch-size", "100"], "100 does not divide"),
    (["--method", "pbt", "--population", "4", "--", "--ultho-clusters", "vf_coef=0.5"], "no cluster has two values"),
    (["--method", "pbt", "--population", "4", "--", "--seed", "3"], "--seed is set by hpo_baselines.py"),
    (["--method", "pbt", "--population", "4", "--", "--no-ultho"], "--no-ultho is set by hpo_baselines.py"),
    (["--method", "pbt", "--population", "4", "--", "--init-from", "x"], "--init-from is set by hpo_baselines.py"),
    (["--method", "pbt", "--population", "4", "--quantile", "0.7"], "--quantile must be in (0, 0.5], got 0.7"),
    (["--method", "pbt", "--population", "4", "--bogus"], "unrecognized arguments: --bogus"),
    (["--method", "pbt", "--population", "4", "--num-cpus", "2", "--ray-address", "127.0.0.1:1"],
     "--num-cpus 2: it sizes the local Ray instance"),
    (["--method", "pbt", "--population", "4", "--wandb-entity", "team"],
     "--wandb-entity and --wandb-group name where --track logs: add --track"),
    (["--method", "pbt", "--population", "4", "--wandb-group", "g"], "add --track"),
    (["--method", "pbt", "--population", "4", "--track", "--wandb-group", "a%b"],
     "--wandb-group 'a%b': W&B names are 1 to 128 characters"),
    (["--method", "pbt", "--population", "4", "--", "--track"],
     "--track after --: put --track and the --wandb-* options before --"),
    (["--method", "pbt", "--population", "4", "--track", "--", "--wandb-project-name", "p"],
     "--wandb-project-name after --"),
]


@pytest.fixture(scope="module")
def bad_input_results(tmp_path_factory):
    base = tmp_path_factory.mktemp("bad")
    dirs = [base / str(k) for k in range(len(BAD_INPUTS))]
    small = ["--num-envs", "4", "--num-steps", "64", "--minibatch-size", "64", "--ultho-clusters", "learning_rate",
             "minibatch_size=32,64,128"]
    commands = []
    for d, (args, _) in zip(dirs, BAD_INPUTS):
        tool, script = (args[:args.index("--")], args[args.index("--") + 1:]) if "--" in args else (args, [])
        commands.append([SCRIPT, *tool, "--study-dir", str(d), "--", *small, *script])
    return list(zip(dirs, run_concurrently(TOOL, commands)))


@pytest.mark.parametrize("case", range(len(BAD_INPUTS)), ids=[" ".join(a) for a, _ in BAD_INPUTS])
def test_bad_input_exits_2_with_one_line_before_ray_starts(bad_input_results, case):
    study_dir, result = bad_input_results[case]
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{TOOL}: error: ") and BAD_INPUTS[case][1] in lines[0], \
        result.stderr
    assert result.stdout == "" and not study_dir.exists()


def test_a_study_directory_of_other_arguments_is_refused(pbt_study):
    study_dir, _ = pbt_study
    result = study(study_dir, "--method", "pbt", "--population", "4", "--keep-checkpoints", "0")
    assert result.returncode == 2 and "holds a study of other arguments" in result.stderr


def test_help_reads_like_documentation():
    result = run(TOOL, "--help")
    assert result.returncode == 0
    for text in ("population-based training (pbt)", "--ray-address", "--interval", "--samples",
                 "python hpo_baselines.py ppo_ultho_minigrid.py --method pbt --population 4 --seed 1"):
        assert text in result.stdout, text


def test_sac_interval_refusal_names_the_sac_flag_that_sets_an_iteration(tmp_path):
    result = run(TOOL, "sac_ultho_dmc.py", "--method", "pbt", "--population", "2", "--interval", "150",
                 "--study-dir", str(tmp_path / "study"), "--", "--env-id", "cheetah-run", "--total-timesteps", "2000",
                 "--ultho-interval", "100")
    assert result.returncode == 2, result.stderr
    assert "--interval 150 is not a whole number of iterations (one iteration is 100 steps: --ultho-interval 100)" \
        in result.stderr
    assert not (tmp_path / "study").exists()

"""Every committed results folder redraws from its committed data alone: a run's files left out of a commit
(an ignore rule, a forgotten `git add`) fail here instead of in a reader's hands."""

import csv
import os
import re
import shlex
import shutil
import subprocess

import pytest

from helpers import REPO, run

RESULTS = os.path.join(REPO, "results")
FOLDERS = sorted(name for name in os.listdir(RESULTS) if os.path.isdir(os.path.join(RESULTS, name, "data")))


def stated(report_dir: str) -> tuple[list[str], int]:
    """The command line a report states in its first lines, and the number of runs it says it read."""
    with open(os.path.join(report_dir, "report.md")) as f:
        match = re.search(r"`python ultho_report\.py ([^`]*)`: (\d+) runs", f.read())
    assert match, f"{report_dir}/report.md does not state its command and run count"
    return shlex.split(match.group(1)), int(match.group(2))


def rows(path: str) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_every_results_folder_with_data_is_found():
    assert "minigrid" in FOLDERS


@pytest.mark.parametrize("folder", FOLDERS)
def test_report_redraws_from_the_committed_data(folder, tmp_path):
    committed = os.path.join(RESULTS, folder)
    args, runs = stated(committed)
    assert args[0] == f"results/{folder}/data", "the committed report was not drawn from the committed data"
    args[args.index("--out") + 1] = str(tmp_path)
    result = run("ultho_report.py", *args)
    assert result.returncode == 0, result.stderr
    assert stated(str(tmp_path))[1] == runs, "the redraw read another number of runs than the committed report"
    assert rows(str(tmp_path / "aggregate.csv")) == rows(os.path.join(committed, "aggregate.csv"))


def test_a_run_left_out_of_the_data_stops_the_report_unless_a_partial_one_is_asked_for(tmp_path):
    data = tmp_path / "data"
    shutil.copytree(os.path.join(RESULTS, "minigrid", "data"), data)
    full_run = data / "sweep-minigrid" / "runs" / "minigrid__MiniGrid-DoorKey-6x6-v0__ultho_c5.0_w10__s1"
    shutil.rmtree(full_run)  # the full ULTHO run of a relay, as an ignore rule would leave it out
    result = run("ultho_report.py", str(data), "--out", str(tmp_path / "report"), "--no-per-run")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"ultho_report.py: error: missing run {full_run} (referred to by ")
    assert "relay_c5.0_w10__s1/relay.json" in lines[0] and "--allow-missing" in lines[0]
    assert not (tmp_path / "report").exists()
    partial = run("ultho_report.py", str(data), "--out", str(tmp_path / "report"), "--no-per-run", "--allow-missing")
    assert partial.returncode == 0, partial.stderr
    assert f"{full_run.name}/summary.json: missing; skipped" in partial.stderr


def test_the_exporter_says_when_git_would_leave_its_files_out(tmp_path):
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    (tmp_path / ".gitignore").write_text("runs/\n")  # the unanchored rule that once swallowed results data
    exported = tmp_path / "results" / "data"
    result = run("ultho_report.py", os.path.join(RESULTS, "pybullet", "data"), "--out", str(tmp_path / "report"),
                 "--no-per-run", "--export-data", str(exported))
    assert result.returncode == 0, result.stderr
    assert "ultho_report.py: warning: git ignores" in result.stderr and "a commit would leave them out" in result.stderr
    (tmp_path / ".gitignore").write_text("/runs/\n")
    shutil.rmtree(exported)
    again = run("ultho_report.py", os.path.join(RESULTS, "pybullet", "data"), "--out", str(tmp_path / "report"),
                "--no-per-run", "--export-data", str(exported))
    assert again.returncode == 0 and "git ignores" not in again.stderr, again.stderr

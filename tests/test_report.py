"""ultho_report.py on run directories made by real tiny MiniGrid runs, and its aggregates on known numbers."""

import csv
import json
import re
import shutil
from collections import defaultdict

import numpy as np
import pytest

from helpers import run, run_concurrently, scalars, summary
from hpo_study import SCRIPT_ARGS
from ultho_reporting.decisions import cumulative_shares, exploration_ratio
from ultho_reporting.references import PROCGEN_EASY, PYBULLET_REFERENCE, REFERENCES, game_of, normalized, reference_of
from ultho_reporting.runs import Run, Study, raw_score
from ultho_reporting.scores import (Efficiency, aggregate_with_interval, coverage_groups, efficiency_of,
                                    steps_to_threshold)
from ultho_reporting.sections import decisions_by_environment, selection_table, settings_in_force

REPORT = "ultho_report.py"
SCRIPT = "ppo_ultho_minigrid.py"
ENVS = ["MiniGrid-Empty-5x5-v0", "MiniGrid-Empty-Random-5x5-v0"]
SEEDS = [1, 2]
ULTHO_POINTS = [(5.0, 10), (1.0, 50)]  # two corners of the paper's (c, W) grid; the other two stay missing
# 4 envs x 64 steps = 256 per rollout, four iterations; minibatch sizes that divide 256.
TINY = ["--num-envs", "4", "--num-steps", "64", "--total-timesteps", "1024", "--minibatch-size", "128",
        "--eval-episodes", "2", "--quiet"]
SPACE = ["--ultho-clusters", "learning_rate", "minibatch_size=64,128,256", "vf_coef"]
METHODS = ["PPO", "ULTHO (c=1, W=50)", "ULTHO (c=5, W=10)", "Relay-ULTHO (c=5, W=10)"]
SOLVE_THRESHOLD = 0.6  # a running mean of 2 logged returns: some tiny runs reach it, others do not (checked)


def sweep_entry(name, env_id, method, c, window, seed, path, status="done", error=None):
    return {"name": name, "script": SCRIPT, "benchmark": "minigrid", "env_id": env_id, "method": method, "c": c,
            "window": window, "seed": seed, "path": path, "status": status, "attempts": 1, "error": error}


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A sweep directory as sweep.py lays it out: PPO and ULTHO at two (c, W) points x two seeds x two
    environments, one finished Relay-ULTHO (its COI and NOI runs made after the full run named them) and one
    failed relay; relay.json and sweep.json written to formats.md."""
    root = tmp_path_factory.mktemp("study")
    jobs, entries = [], []
    for env_id in ENVS:
        for seed in SEEDS:
            methods = [("ppo", None, None)] + [("ultho", c, w) for c, w in ULTHO_POINTS]
            for method, c, window in methods:
                name = f"{env_id}__{method}{'' if c is None else f'_c{c:g}_w{window}'}__{seed}"
                extra = ["--no-ultho"] if c is None else SPACE + ["--ultho-c", str(c), "--ultho-window", str(window)]
                jobs.append(TINY + extra + ["--env-id", env_id, "--seed", str(seed), "--runs-dir",
                                            str(root / "runs"), "--run-name", name])
                # One finished run that sweep.json had not yet heard of (the sweep stopped before it could).
                stale = (env_id, method, seed) == (ENVS[1], "ppo", 2)
                entries.append(sweep_entry(name, env_id, method, c, window, seed, f"runs/{name}",
                                           "running" if stale else "done"))
    for result in run_concurrently(SCRIPT, jobs):
        assert result.returncode == 0, result.stderr

    full_run = root / "runs" / f"{ENVS[0]}__ultho_c5_w10__1"
    full = summary(str(full_run))
    relay_dir = root / "relays" / "relay_1"
    relay_runs = {"coi": full["bandit"]["coi"], "noi": full["bandit"]["noi"]}
    clusters = {"learning_rate": ["learning_rate"], "minibatch_size": ["minibatch_size=64,128,256"],
                "vf_coef": ["vf_coef"]}
    results = run_concurrently(SCRIPT, [
        TINY + ["--ultho-clusters", *clusters[cluster], "--env-id", ENVS[0], "--seed", "1", "--runs-dir",
                str(relay_dir), "--run-name", role]
        for role, cluster in relay_runs.items()])
    assert all(r.returncode == 0 for r in results), [r.stderr for r in results]
    scores = {"full": full["final_score"]} | {role: summary(str(relay_dir / role))["final_score"]
                                              for role in relay_runs}
    winner = "coi" if scores["coi"] >= scores["noi"] else "noi"
    relay = {"format": 1, "script": SCRIPT, "script_args": TINY, "env_id": ENVS[0], "seed": 1, "status": "done",
             "full_run": str(full_run), "coi": relay_runs["coi"], "noi": relay_runs["noi"], "coi_run": "coi",
             "noi_run": "noi", "final_scores": scores, "winner": winner, "winner_run": winner,
             "final_score": scores[winner], "total_timesteps": 3 * 1024}
    (relay_dir / "relay.json").write_text(json.dumps(relay))
    entries.append(sweep_entry("relay_1", ENVS[0], "relay", 5.0, 10, 1, "relays/relay_1"))
    entries.append(sweep_entry("relay_2", ENVS[0], "relay", 5.0, 10, 2, "relays/relay_2", "failed", "exit status 1"))
    entries.append(sweep_entry("ppo_3", ENVS[1], "ppo", None, None, 3, "runs/ppo_3", "running"))  # never started
    grid = {"scripts": [SCRIPT], "env_ids": ENVS, "methods": ["ppo", "ultho", "relay"], "c": [1.0, 5.0],
            "window": [10, 50], "seeds": SEEDS, "total_timesteps": 1024, "extra_args": TINY}
    (root / "sweep.json").write_text(json.dumps({"format": 1, "grid": grid, "runs": entries}))
    return root


@pytest.fixture(scope="module")
def reports(study, tmp_path_factory):
    """The full report, and the same --seed again without the per-run figures, both at once."""
    out = tmp_path_factory.mktemp("reports")
    common = [str(study), "--seed", "7", "--reps", "5000", "--solve-threshold", str(SOLVE_THRESHOLD),
              "--solve-window", "2"]
    results = run_concurrently(REPORT, [common + ["--out", str(out / "a")],
                                        common + ["--out", str(out / "b"), "--no-per-run"]])
    for result in results:
        assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    assert not [line for line in results[0].stderr.splitlines() if "warning" in line]
    return {name: out / name for name in ("a", "b")}


def table(out, benchmark="minigrid") -> dict[str, dict]:
    """Each method's first aggregate row: the one over the widest set of environments it covers."""
    rows: dict[str, dict] = {}
    with open(out / "aggregate.csv") as f:
        for row in csv.DictReader(f):
            if row["benchmark"] == benchmark:
                rows.setdefault(row["method"], row)
    return rows


def test_every_figure_exists_and_report_md_links_it(reports):
    out = reports["a"]
    report = (out / "report.md").read_text()
    linked = re.findall(r"\]\(([^)]+)\)", report)
    assert linked and all((out / name).is_file() for name in linked)
    figures = {str(p.relative_to(out)) for p in out.rglob("*.png")}
    assert figures <= set(linked)
    expected = {"curves_minigrid.png", "robustness_minigrid.png", "aggregate.csv"}
    for point in ("c_1_W_50", "c_5_W_10"):
        expected |= {f"decision_minigrid_ULTHO_{point}.png", f"bounds_minigrid_ULTHO_{point}.png"}
    assert expected <= set(linked)
    per_run = [name for name in linked if name.startswith("runs/")]
    assert len(per_run) == len(ENVS) * len(SEEDS) * len(ULTHO_POINTS)
    assert all((out / name).stat().st_size > 10_000 for name in linked if name.endswith(".png"))


def test_report_says_what_is_missing(reports):
    report = (reports["a"] / "report.md").read_text()
    missing = report.split("## Missing and skipped")[1]
    assert "- sweep run `relay_2` (relay, MiniGrid-Empty-5x5-v0, seed 2) failed: exit status 1\n" in missing
    assert f"- sweep run `ppo_3` (ppo, {ENVS[1]}, seed 3) has not finished (sweep.json: running)\n" in missing
    assert f"{ENVS[1]}__ppo__2" not in missing  # finished, though its sweep.json entry still said running
    assert (f"No scored ULTHO runs at {ENVS[0]} (c=1, W=10), {ENVS[0]} (c=5, W=50), {ENVS[1]} (c=1, W=10), "
            f"{ENVS[1]} (c=5, W=50).") in report
    # The single relay has a run on the first environment only: its own aggregate table, over that one.
    assert f"Over 2 environments: {ENVS[0]}, {ENVS[1]}." in report and f"Over 1 environment: {ENVS[0]}." in report
    relay_row = next(line for line in report.splitlines() if line.startswith("| Relay-ULTHO (c=5, W=10) | "))
    assert relay_row.endswith(" (1) | – |")


def raw_scores(study) -> list[tuple[str, str, float, float | None]]:
    """(environment, method, final score, evaluation score) of every scored entry, from the summaries."""
    summaries = [summary(str(d)) for d in (study / "runs").iterdir()]
    relay = json.loads((study / "relays" / "relay_1" / "relay.json").read_text())
    winner = summary(str(study / "relays" / "relay_1" / relay["winner_run"]))
    return [(s["env_id"], "PPO" if not s["ultho"] else f"ULTHO (c={s['bandit']['c']:g}, W={s['bandit']['window']})",
             s["final_score"], s["eval"]["mean_return"]) for s in summaries] + \
        [(ENVS[0], METHODS[3], relay["final_score"], winner["eval"]["mean_return"])]


def test_aggregate_table_has_minigrid_returns_as_they_are_over_the_environments_each_method_covers(study, reports):
    rows = table(reports["a"])
    assert list(rows) == METHODS
    raw = raw_scores(study)
    for method in METHODS:
        scores = [x for _, m, x, _ in raw if m == method]
        assert float(rows[method]["mean"]) == pytest.approx(np.mean(scores))
        assert int(rows[method]["runs"]) == len(scores)
    assert rows["PPO"]["environments"] == " ".join(ENVS) and rows[METHODS[3]]["environments"] == ENVS[0]
    assert rows["PPO"]["budget_steps_min"] == rows["PPO"]["budget_steps_max"] == "1024"
    assert rows[METHODS[3]]["budget_steps_min"] == "3072"  # three runs
    with open(reports["a"] / "aggregate.csv") as f:
        narrower = [row["method"] for row in csv.DictReader(f) if row["environments"] == ENVS[0]]
    assert narrower[0] == "PPO" and METHODS[3] in narrower  # compared over the one environment they share


def test_runs_shorter_than_the_solve_window_are_scored_at_their_last_step(study, tmp_path):
    """The tiny runs log at most 4 returns; with a window of 10 each run's running score is the mean of all of
    them, at its last logged step (before, a threshold some run reached indexed past its curve and stopped the
    report)."""
    threshold = 0.05
    result = run(REPORT, str(study / "runs"), "--out", str(tmp_path / "out"), "--reps", "100", "--no-per-run",
                 "--solve-window", "10", "--solve-threshold", str(threshold))
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    report = (tmp_path / "out" / "report.md").read_text()
    assert "A run that logged fewer than 10 returns has a running score only at its last logged step" in report
    block = report.split("### Sample efficiency")[1].split("\n\n")[2]
    rows = {line.split(" | ")[0].removeprefix("| "): line.split(" | ")[1:] for line in block.splitlines()[2:]}
    reached_any = False
    for method in METHODS[:3]:
        found = []
        for run_dir in sorted((study / "runs").iterdir()):
            s = summary(str(run_dir))
            label = "PPO" if not s["ultho"] else f"ULTHO (c={s['bandit']['c']:g}, W={s['bandit']['window']})"
            if label == method and s["env_id"] == ENVS[0]:
                curve = scalars(str(run_dir))["charts/episodic_return"]
                assert 1 < len(curve) < 10
                reached = np.mean([value for _, value in curve]) >= threshold
                reached_any |= reached
                found.append((curve[-1][0] if reached else None, s["global_step"]))
        assert rows[method][0] == Efficiency([f for f, _ in found], [b for _, b in found]).text()
    assert reached_any, "no tiny run reached the threshold: the old failure was not exercised"


def test_a_score_does_not_depend_on_the_other_runs_present(study, reports, tmp_path):
    """Only the PPO runs: PPO's aggregate is what it was beside ULTHO and Relay-ULTHO."""
    alone = tmp_path / "ppo"
    for run_dir in (study / "runs").iterdir():
        if "__ppo__" in run_dir.name:
            shutil.copytree(run_dir, alone / run_dir.name)
    result = run(REPORT, str(alone), "--out", str(tmp_path / "out"), "--seed", "7", "--reps", "5000")
    assert result.returncode == 0, result.stderr
    assert table(tmp_path / "out")["PPO"] == table(reports["a"])["PPO"]


def test_per_environment_tables_hold_each_methods_mean_over_seeds(study, reports):
    report = (reports["a"] / "report.md").read_text()
    final_table, eval_table = [block for block in report.split("\n\n") if block.startswith("| method | " + ENVS[0])][:2]
    raw = raw_scores(study)
    for block, column in ((final_table, 2), (eval_table, 3)):
        rows = {line.split(" | ")[0].removeprefix("| "): line.split(" | ")[1:] for line in block.splitlines()[2:]}
        for method in METHODS:
            for k, env in enumerate(ENVS):
                values = [entry[column] for entry in raw if entry[0] == env and entry[1] == method]
                cell = rows[method][k].removesuffix(" |")
                if not values:
                    assert cell == "–"
                    continue
                assert cell.startswith(f"{np.mean(values):.2f} [") and cell.endswith(f"] ({len(values)})"), cell


def test_sample_efficiency_table_from_the_real_curves(study, reports):
    """Recomputed by hand from each run's TensorBoard return curve: running mean of 2, first step >= threshold."""
    report = (reports["a"] / "report.md").read_text()
    block = report.split("### Sample efficiency")[1].split("\n\n")[2]
    rows = {line.split(" | ")[0].removeprefix("| "): line.split(" | ")[1:] for line in block.splitlines()[2:]}
    expected = defaultdict(list)
    for run_dir in sorted((study / "runs").iterdir()):
        s = summary(str(run_dir))
        label = "PPO" if not s["ultho"] else f"ULTHO (c={s['bandit']['c']:g}, W={s['bandit']['window']})"
        curve = scalars(str(run_dir))["charts/episodic_return"]
        running = [(curve[i - 1][1] + curve[i][1]) / 2 for i in range(1, len(curve))]
        first = next((curve[i + 1][0] for i, x in enumerate(running) if x >= SOLVE_THRESHOLD), None)
        expected[(label, s["env_id"])].append((first, s["global_step"]))
    for (label, env), found in expected.items():
        steps = [budget if first is None else first for first, budget in found]
        reached = sum(first is not None for first, _ in found)
        cell = rows[label][ENVS.index(env)]
        assert cell == Efficiency([f for f, _ in found], [b for _, b in found]).text()
        assert cell.endswith(f"({reached}/{len(found)})") and (cell.startswith("≥ ") == (reached < len(found)))
        assert Efficiency([f for f, _ in found], [b for _, b in found]).censored_mean == pytest.approx(np.mean(steps))
    assert any(first is not None for found in expected.values() for first, _ in found), "threshold never reached"
    assert any(first is None for found in expected.values() for first, _ in found), "threshold always reached"


def test_report_redraws_from_the_exported_data(study, reports, tmp_path):
    """--export-data keeps summaries, indexes and curves; the report drawn from it equals the original."""
    data, out = tmp_path / "data", tmp_path / "redrawn"
    common = ["--seed", "7", "--reps", "5000", "--solve-threshold", str(SOLVE_THRESHOLD), "--solve-window", "2"]
    result = run(REPORT, str(study), "--out", str(tmp_path / "first"), "--export-data", str(data), *common)
    assert result.returncode == 0, result.stderr
    assert not list(data.rglob("events.out.tfevents*")) and not list(data.rglob("checkpoint.pt"))
    assert len(list(data.rglob("scalars.csv"))) == len(list(study.rglob("summary.json")))
    result = run(REPORT, str(data / study.name), "--out", str(out), *common)
    assert result.returncode == 0 and "warning" not in result.stderr, result.stderr
    assert table(out) == table(reports["a"])

    def body(path):
        return (path / "report.md").read_text().split("\n", 3)[3].replace(str(data / study.name), str(study))

    assert body(out) == body(reports["a"])
    assert {p.name for p in out.rglob("*.png")} == {p.name for p in reports["a"].rglob("*.png")}


def test_each_interval_contains_its_point_estimate(reports):
    for row in table(reports["a"]).values():
        for name in ("mean", "iqm"):
            assert float(row[f"{name}_low"]) <= float(row[name]) <= float(row[f"{name}_high"])


def test_same_seed_gives_identical_intervals(reports):
    assert table(reports["a"]) == table(reports["b"])
    assert not (reports["b"] / "runs").exists()


def test_decision_shares_come_from_the_selections(reports, study):
    """The per-run shares end at the run's selection counts: the credited ones in summary.json plus the last."""
    reader = Study()
    reader.load_run(str(study / "runs" / f"{ENVS[0]}__ultho_c5_w10__1"))
    (run,) = reader.runs
    shares = cumulative_shares(run)
    iterations = summary(run.path)["iterations"]
    assert shares.shape == (iterations, 1 + 3) and np.allclose(shares[:, 1:].sum(1), 1)
    counts = np.rint(shares[-1, 1:] * iterations)
    credited = np.array(list(summary(run.path)["bandit"]["selections"].values()))
    assert counts.sum() == credited.sum() + 1 and ((counts - credited) >= 0).all()


def diverge(run_dir, iteration: int, global_step: int) -> None:
    """Rewrites a real run's summary.json as a script writes it for a run whose loss became non-finite: where it
    stopped, its final score as it was, no evaluation."""
    path = run_dir / "summary.json"
    record = json.loads(path.read_text())
    record |= {"diverged": {"what": "loss", "iteration": iteration, "global_step": global_step},
               "global_step": global_step, "iterations": iteration,
               "eval": {"episodes": 0, "mean_return": None, "std_return": None, "returns": []}}
    path.write_text(json.dumps(record))


def test_diverged_runs_count_with_what_they_reached_and_are_named(study, reports, tmp_path):
    """A PPO run and the relay's winning run diverged: every mean, IQM and interval is what it was (no survivor
    bias), the counts and a list say which diverged, the evaluation tables say whom they leave out."""
    copy = tmp_path / "study"
    shutil.copytree(study, copy)
    ppo = copy / "runs" / f"{ENVS[0]}__ppo__1"
    diverge(ppo, 2, 512)
    relay = json.loads((copy / "relays" / "relay_1" / "relay.json").read_text())
    diverge(copy / "relays" / "relay_1" / relay["winner_run"], 3, 768)
    common = ["--seed", "7", "--reps", "5000", "--solve-threshold", str(SOLVE_THRESHOLD), "--solve-window", "2",
              "--no-per-run"]
    result = run(REPORT, str(copy), "--out", str(tmp_path / "out"), *common)
    assert result.returncode == 0 and "warning" not in result.stderr, result.stderr

    rows, before = table(tmp_path / "out"), table(reports["b"])
    assert rows["PPO"].pop("budget_steps_min") == "512"  # the steps it ran; the relay's budget is its relay.json's
    before["PPO"].pop("budget_steps_min")
    assert rows == before
    report = (tmp_path / "out" / "report.md").read_text()
    final_table, eval_table = [block for block in report.split("\n\n") if block.startswith("| method | " + ENVS[0])][:2]
    cells = {(line.split(" | ")[0].removeprefix("| "), which): line.split(" | ")[1].removesuffix(" |")
             for which, block in (("final", final_table), ("eval", eval_table)) for line in block.splitlines()[2:]}
    assert cells[("PPO", "final")].endswith("] (2, 1 diverged)")
    assert cells[("PPO", "eval")].endswith("] (1; 1 diverged left out)")
    assert cells[(METHODS[3], "final")].endswith("] (1, 1 diverged)")
    assert cells[(METHODS[3], "eval")] == "– (0; 1 diverged left out)"
    assert cells[(METHODS[1], "final")].endswith("] (2)")
    assert f"\n- `{ppo}` (PPO, {ENVS[0]}, seed 1): non-finite loss at iteration 2, step 512\n" in report
    assert (f"\n- `{copy / 'relays' / 'relay_1'}` ({METHODS[3]}, {ENVS[0]}, seed 1): non-finite loss at iteration 3, "
            "step 768 (its winning run)\n") in report
    assert "| PPO | 2 | 4 (1 diverged) | " in report and f"| {METHODS[3]} | 1 | 1 (1 diverged) | " in report
    # Its curve counts to the end of the --total-timesteps it was given, where its peers' do: the sample
    # efficiency is what it was.
    efficiency = report.split("### Sample efficiency")[1].split("###")[0]
    assert efficiency == (reports["b"] / "report.md").read_text().split("### Sample efficiency")[1].split("###")[0]
    reader = Study()
    reader.load_run(str(ppo))
    assert (reader.runs[0].budget, reader.runs[0].curve_budget) == (512, 1024)
    assert reader.runs[0].diverged == {"what": "loss", "iteration": 2, "global_step": 512}
    # Runs without the key (every summary written before scripts recorded divergence) say nothing of it.
    assert "diverged" not in (reports["b"] / "report.md").read_text()


def test_a_diverged_record_not_in_the_format_is_a_damaged_summary(study, tmp_path):
    run_dir = tmp_path / "run"
    shutil.copytree(study / "runs" / f"{ENVS[0]}__ppo__1", run_dir)
    record = json.loads((run_dir / "summary.json").read_text())
    (run_dir / "summary.json").write_text(json.dumps(record | {"diverged": {"what": "loss"}}))
    reader = Study()
    reader.load_run(str(run_dir))
    assert reader.runs == [] and len(reader.warnings) == 1
    assert "not in the summary.json format (KeyError: 'iteration'); skipped" in reader.warnings[0]
    (run_dir / "summary.json").write_text(json.dumps(record | {"diverged": None}))  # as a finished run writes it
    fresh = Study()
    fresh.load_run(str(run_dir))
    assert fresh.runs[0].diverged is None and fresh.runs[0].curve_budget == record["global_step"]


def test_damaged_files_are_named_once_each_and_skipped(study, tmp_path):
    copy = tmp_path / "study"
    shutil.copytree(study, copy)
    runs = sorted((copy / "runs").iterdir())
    (runs[0] / "summary.json").write_text("{not json")
    events = next(p for p in runs[1].iterdir() if p.name.startswith("events.out.tfevents"))
    events.write_bytes(events.read_bytes()[: events.stat().st_size // 2])
    (runs[2] / "summary.json").unlink()
    (copy / "relays" / "relay_1" / "relay.json").write_text('{"format": 1}')
    # A Procgen run without TensorBoard events next to the MiniGrid ones: mixed benchmarks, a missing file.
    procgen = copy / "procgen_run"
    procgen.mkdir()
    (procgen / "summary.json").write_text(json.dumps(
        {"script": "ppo_ultho_procgen", "env_id": "procgen-bigfish-v0", "seed": 1, "global_step": 1024,
         "ultho": False, "bandit": None, "final_score": 30.0, "train_score": 30.0, "test_score": 20.5}))
    result = run(REPORT, str(copy), "--out", str(tmp_path / "out"), "--reps", "500", "--no-per-run")
    assert result.returncode == 0 and "Traceback" not in result.stderr, result.stderr
    warnings = result.stderr.splitlines()[:-1]
    assert all(line.startswith("ultho_report.py: warning: ") for line in warnings), warnings
    named = {runs[0] / "summary.json": "unreadable", events: "truncated", runs[2]: "no summary.json",
             copy / "relays" / "relay_1" / "relay.json": "relay.json format", procgen: "no TensorBoard event files"}
    for path, what in named.items():
        assert len([line for line in warnings if f" {path}: " in line and what in line]) == 1, (path, warnings)
    assert len(warnings) == len(named)
    assert float(table(tmp_path / "out", "procgen")["PPO"]["mean"]) == pytest.approx(0.5)  # (20.5 - 1) / (40 - 1)
    report = (tmp_path / "out" / "report.md").read_text()
    assert "## Procgen" in report and "## MiniGrid" in report and "## Missing and skipped" in report


def test_bad_arguments_are_one_line_and_exit_2(tmp_path):
    (tmp_path / "empty").mkdir()
    missing, empty, help_ = run_concurrently(REPORT, [[str(tmp_path / "nowhere")], [str(tmp_path / "empty")],
                                                      ["--help"]])
    for result, what in ((missing, f"no such path: {tmp_path / 'nowhere'}"), (empty, "no run found below")):
        assert result.returncode == 2 and result.stderr.count("\n") == 1, result.stderr
        assert result.stderr.startswith("ultho_report.py: error: ") and what in result.stderr
    assert help_.returncode == 0 and "python ultho_report.py runs/ --out report/" in help_.stdout
    assert not (tmp_path / "report").exists()


# ---------------------------------------------------------------------- scores and aggregates, known numbers
def test_procgen_uses_the_test_score_with_the_easy_constants():
    shaped = {"script": "ppo_ultho_procgen", "env_id": "procgen-bigfish-v0", "final_score": 30.0,
              "train_score": 30.0, "test_score": 20.5}
    raw, note = raw_score(shaped, "procgen")
    assert (raw, note) == (20.5, None)
    assert normalized("procgen", shaped["env_id"], raw) == pytest.approx(0.5)  # (20.5 - 1) / (40 - 1)
    raw, note = raw_score(shaped | {"test_score": None}, "procgen")
    assert raw == 30.0 and "training score" in note
    assert normalized("procgen", "starpilot", 64) == pytest.approx(1.0)
    assert normalized("procgen", "procgen:procgen-fruitbot-v0", -1.5) == pytest.approx(0.0)
    assert game_of("procgen-miner-v0", PROCGEN_EASY) == "miner" and game_of("procgen-maze-v0", PROCGEN_EASY) == "maze"


def test_ale_is_human_normalized_and_unknown_games_are_not_scored():
    shaped = {"script": "ppo_ultho_atari", "env_id": "ALE/Qbert-v5", "final_score": 6809.45,
              "human_normalized_score": 0.5}
    raw, _ = raw_score(shaped, "atari")
    assert normalized("atari", shaped["env_id"], raw) == pytest.approx(0.5)  # midway random 163.9, human 13455
    assert normalized("atari", "BattleZoneNoFrameskip-v4", 37187.5) == pytest.approx(1.0)
    assert normalized("atari", "ALE/DoubleDunk-v5", -18.6) == pytest.approx(0.0)
    assert normalized("atari", "ALE/Pong-v5", 21.0) is None


def test_mean_and_iqm_of_a_known_score_matrix():
    # Two games x four seeds. All eight scores sorted: 0 1 2 3 4 5 6 10.
    # mean = 31 / 8 = 3.875; IQM drops int(0.25 * 8) = 2 at each end: (2 + 3 + 4 + 5) / 4 = 3.5.
    strata = [np.array([0.0, 1.0, 2.0, 10.0]), np.array([3.0, 4.0, 5.0, 6.0])]
    assert aggregate_with_interval(strata, "mean", 0, 1000)[0] == pytest.approx(3.875)
    assert aggregate_with_interval(strata, "IQM", 0, 1000)[0] == pytest.approx(3.5)
    # Five scores: int(1.25) = 1 dropped at each end, as scipy.stats.trim_mean(x, 0.25): (2 + 3 + 4) / 3 = 3.
    assert aggregate_with_interval([np.array([1.0, 2.0, 3.0, 4.0, 100.0])], "IQM", 0, 1000)[0] == pytest.approx(3.0)


def test_bootstrap_is_stratified_by_game_and_seeded():
    # Game A always scores 0 and game B always 1: every stratified resample keeps two of each, so the mean is
    # exactly 0.5 in every resample (pooling the games would let it spread from 0 to 1).
    point, low, high = aggregate_with_interval([np.zeros(2), np.ones(2)], "mean", 3, 2000)
    assert point == low == high == 0.5
    strata = [np.array([0.1, 0.35, 0.2, 0.9, 0.55]), np.array([0.3, 0.8, 0.45, 0.6, 0.05])]
    for name in ("mean", "IQM"):
        point, low, high = aggregate_with_interval(strata, name, 1, 2000)
        assert low <= point <= high and low < high
        assert aggregate_with_interval(strata, name, 1, 2000) == (point, low, high)
        assert aggregate_with_interval(strata, name, 2, 2000)[1:] != (low, high)


def test_pybullet_and_minigrid_use_fixed_references():
    low, high = PYBULLET_REFERENCE["HalfCheetahBulletEnv"]
    assert normalized("pybullet", "HalfCheetahBulletEnv-v0", high) == pytest.approx(1.0)
    assert normalized("pybullet", "HalfCheetahBulletEnv-v0", (low + high) / 2) == pytest.approx(0.5)
    assert normalized("pybullet", "InvertedPendulumBulletEnv-v0", 1000.0) is None
    assert normalized("minigrid", "MiniGrid-DoorKey-6x6-v0", 0.93) == pytest.approx(0.93)


def test_steps_to_threshold_by_hand():
    # Running mean of 3 logged returns: (0.2, 0.5, 0.8) at step 30 = 0.5; (0.5, 0.8, 0.95) at 40 = 0.75;
    # (0.8, 0.95, 1.0) at 50 = 0.9167 -> first reaches 0.9 at step 50, 0.7 at step 40, never 0.95.
    curve = np.array([[10, 0.2], [20, 0.5], [30, 0.8], [40, 0.95], [50, 1.0]])
    assert steps_to_threshold(curve, "minigrid", "MiniGrid-Empty-5x5-v0", 0.9, 3) == 50
    assert steps_to_threshold(curve, "minigrid", "MiniGrid-Empty-5x5-v0", 0.7, 3) == 40
    assert steps_to_threshold(curve, "minigrid", "MiniGrid-Empty-5x5-v0", 0.95, 3) is None
    assert steps_to_threshold(curve, "minigrid", "MiniGrid-Empty-5x5-v0", 0.8, 1) == 30
    # On the fixed scale: Procgen coinrun (5, 10), so a return of 9.5 is 0.9.
    assert steps_to_threshold(np.array([[1, 9.0], [2, 9.5]]), "procgen", "coinrun", 0.9, 1) == 2
    found = Efficiency([50, None, 30], [100, 100, 100])
    assert (found.reached, found.censored_mean, found.text()) == (2, 60.0, "≥ 60 (2/3)")
    assert Efficiency([10, 20], [100, 100]).text() == "15 (2/2)"
    assert Efficiency([96_938.7, 120_000], [499_712] * 2).text() == "108k (2/2)"
    assert Efficiency([1_500_000, 1_000_000], [2_000_000] * 2).text() == "1.25M (2/2)"
    assert Efficiency([12_345, 54_321], [499_712] * 2).text() == "33,333 (2/2)"


@pytest.mark.parametrize("window", [5, 10])
def test_a_curve_shorter_than_the_window_is_scored_by_its_mean_at_its_last_step(window):
    # Three logged returns, fewer than the window: the running score exists once, at the last step (30), and is
    # the mean of all three, (0.2 + 0.5 + 0.8) / 3 = 0.5, as it is the mean of the first `window` returns at
    # step `window` of a longer curve. Before, np.convolve swapped its arguments: 3 * [0.3] or 8 * [0.15]...
    curve = np.array([[10, 0.2], [20, 0.5], [30, 0.8]])
    assert steps_to_threshold(curve, "minigrid", "MiniGrid-Empty-5x5-v0", 0.5, window) == 30
    assert steps_to_threshold(curve, "minigrid", "MiniGrid-Empty-5x5-v0", 0.51, window) is None
    # ...and a low threshold indexed past the curve's end (IndexError).
    assert steps_to_threshold(curve, "minigrid", "MiniGrid-Empty-5x5-v0", 0.1, window) == 30
    # Three returns of 1.0 average 1.0, not 3 / window.
    solved = np.array([[10, 1.0], [20, 1.0], [30, 1.0]])
    assert steps_to_threshold(solved, "minigrid", "MiniGrid-Empty-5x5-v0", 0.9, window) == 30
    assert efficiency_of([Run("p", "minigrid", "MiniGrid-Empty-5x5-v0", "ppo", None, None, 1, 30, 1.0, curve=solved,
                              curve_budget=30)], 0.9, window).text() == "30 (1/1)"


def test_each_aggregate_compares_every_method_that_covers_its_environments_over_those_alone():
    def entry(label, env):
        run = Run("p", "minigrid", env, "ppo", None, None, 1, 1, 0.5, score=0.5)
        run.label = label
        return run

    runs = [entry("A", "x"), entry("A", "y"), entry("B", "y"), entry("B", "x"), entry("C", "x"), entry("D", "z")]
    runs.append(entry("E", "x"))
    runs[-1].score = None  # no scored run: in no aggregate
    assert coverage_groups(runs, ["A", "B", "C", "D", "E"]) == [(["x", "y"], ["A", "B"]), (["x"], ["A", "B", "C"]),
                                                                 (["z"], ["D"])]


def test_bandit_variants_are_methods_of_their_own(tmp_path):
    """A Thompson-sampling run beside a paper ULTHO run: its own label (no c, which it does not use), its own row."""
    jobs = [TINY + SPACE + ["--env-id", ENVS[0], "--seed", "1", "--runs-dir", str(tmp_path / "runs"),
                            "--run-name", name]
            + extra for name, extra in (("paper", []), ("ts", ["--ultho-strategy", "ts", "--ultho-credit",
                                                                "improvement", "--ultho-scale", "running"]))]
    for result in run_concurrently(SCRIPT, jobs):
        assert result.returncode == 0, result.stderr
    result = run(REPORT, str(tmp_path / "runs"), "--out", str(tmp_path / "out"), "--reps", "500", "--no-per-run")
    assert result.returncode == 0, result.stderr
    rows = table(tmp_path / "out")
    assert list(rows) == ["ULTHO (c=5, W=10)", "ULTHO ts/improvement/running (W=10)"]
    assert float(rows["ULTHO ts/improvement/running (W=10)"]["mean"]) == pytest.approx(
        summary(str(tmp_path / "runs" / "ts"))["final_score"])
    report = (tmp_path / "out" / "report.md").read_text()
    assert "#### ULTHO ts/improvement/running (W=10)" in report
    assert "decision_minigrid_ULTHO_ts_improvement_running_W_10.png" in report


def test_hpo_studies_are_rows_with_their_whole_budget(pbt_study, tmp_path):
    """The real PBT study of the shared fixture (population 3, exploits every two iterations) beside a PPO run of
    the same settings: the study is one entry scored by its best trial's final score, with the population's steps
    as its budget; its trials are not PPO runs; its schedule is drawn."""
    study_dir, _ = pbt_study
    result = run(SCRIPT, *SCRIPT_ARGS, "--no-ultho", "--total-timesteps", "1024", "--quiet", "--runs-dir",
                 str(tmp_path / "runs"), "--run-name", "ppo")
    assert result.returncode == 0, result.stderr
    result = run(REPORT, str(study_dir), str(tmp_path / "runs"), "--out", str(tmp_path / "out"),
                 "--reps", "500", "--no-per-run")
    assert result.returncode == 0 and "warning" not in result.stderr, result.stderr
    record = json.loads((study_dir / "study.json").read_text())
    finals = [summary(str(study_dir / t["run_dir"]))["final_score"] for t in record["trials"]]
    rows = table(tmp_path / "out")
    assert list(rows) == ["PPO", "PBT (population 3)"]
    assert int(rows["PPO"]["runs"]) == 1  # the trials are the study's, not PPO runs
    pbt = rows["PBT (population 3)"]
    assert int(pbt["runs"]) == 1 and float(pbt["mean"]) == pytest.approx(max(finals))
    assert int(pbt["budget_steps_min"]) == int(pbt["budget_steps_max"]) == 3 * 1024 == record["budget"]["total_steps"]
    report = (tmp_path / "out" / "report.md").read_text()
    seen = record["max_observed_score"]
    assert f"({seen['trial']}, {seen['step']:,}) | {len(record['exploits'])} |" in report
    assert "![settings schedules](schedules_minigrid.png)" in report
    assert (tmp_path / "out" / "schedules_minigrid.png").is_file()


@pytest.mark.parametrize("env_id", ["AntBulletEnv-v0", "HalfCheetahBulletEnv-v0", "HopperBulletEnv-v0",
                                    "Walker2DBulletEnv-v0", "ALE/Qbert-v5", "Qbert", "procgen-bigfish-v0",
                                    "starpilot"])
def test_every_reference_environment_is_normalized_by_its_own_references(env_id):
    benchmark = "pybullet" if "Bullet" in env_id else "atari" if "Qbert" in env_id else "procgen"
    low, high = reference_of(benchmark, env_id)
    assert game_of(env_id, REFERENCES[benchmark]).lower() in env_id.lower().replace("-", "")
    assert normalized(benchmark, env_id, high) == 1.0
    assert normalized(benchmark, env_id, low) == 0.0


def test_exploration_ratio_and_decisions_by_environment_by_hand():
    space = {"learning_rate": [1e-3, 2e-3], "vf_coef": [0.5, 1.0]}

    def ucb_run(env: str, selections: dict, ucb: list, bonus: list) -> Run:
        steps = np.arange(1, len(ucb) + 1, dtype=float)
        series = {f"ultho/{kind}/{cluster}": np.column_stack([steps, [row[k] for row in rows]])
                  for kind, rows in (("ucb", ucb), ("bonus", bonus)) for k, cluster in enumerate(space)}
        return Run("p", "pybullet", env, "ultho", 5.0, 10, 1, 1, 0.0, series=series, search_space=space,
                   value_selections=selections)

    # Second half (rows 2 and 3): utilities 3-0.5 and 1-0.5 (spread 2, mean bonus 0.5: 0.25), then equal
    # utilities (no spread: left out). The first half, whatever it holds, does not count.
    run = ucb_run("A", {"learning_rate": [1, 2], "vf_coef": [3, 4]},
                  ucb=[[100, 0], [0, 100], [3, 1], [2, 2]], bonus=[[9, 9], [9, 9], [0.5, 0.5], [1, 1]])
    assert exploration_ratio(run) == pytest.approx(0.25)
    other = ucb_run("A", {"learning_rate": [5, 5], "vf_coef": [0, 0]},
                    ucb=[[0, 0], [0, 0], [4, 0], [4, 0]], bonus=[[1, 1], [1, 1], [1, 1], [2, 2]])
    assert exploration_ratio(other) == pytest.approx(0.375)  # 1/4 and 2/4
    lines = decisions_by_environment([run, other])
    # Pooled: learning_rate 3 + 10 of 20, vf_coef 7 of 20; per run 30%-100% and 0%-70%; median ratio 0.3125.
    assert lines[2] == "| A | 2 | 65.0 (30–100) | 35.0 (0–70) | 0.31 |"
    assert exploration_ratio(Run("p", "pybullet", "A", "ultho", 5.0, 10, 1, 1, 0.0, search_space=space)) is None


@pytest.mark.parametrize("variants, extra_args, points", [
    (None, [], {(5.0, 10)}), (["ucb:level:none", "ts:level:none"], [], {(5.0, 10)}),
    (["ucb:level:running"], [], set()), (None, ["--ultho-utility", "authors-return"], set()),
    (None, ["--ultho-clusters", "update_epochs=10,5"], set()), (None, ["--update-epochs", "5"], {(5.0, 10)})])
def test_only_the_papers_bandit_makes_a_sweep_grid_point_of_the_robustness_figure(tmp_path, variants, extra_args,
                                                                                   points):
    grid = {"scripts": ["ppo_ultho_pybullet.py"], "env_ids": ["HopperBulletEnv-v0"], "methods": ["ultho"],
            "c": [5.0], "window": [10], "points": [[5.0, 10]], "seeds": [1], "extra_args": extra_args}
    if variants is not None:  # a sweep.json without the key ran the paper's bandit
        grid["variants"] = variants
    (tmp_path / "sweep").mkdir()
    (tmp_path / "sweep" / "sweep.json").write_text(json.dumps({"format": 1, "grid": grid, "runs": []}))
    study = Study()
    study.discover([str(tmp_path)])
    assert study.grid.get(("pybullet", "HopperBulletEnv-v0"), set()) == points


def test_a_strict_rotation_credits_every_value_equally_often_to_within_one_by_hand():
    def counted(selections: dict) -> Run:
        space = {cluster: list(range(len(counts))) for cluster, counts in selections.items()}
        return Run("p", "pybullet", "A", "ultho", 5.0, 10, 1, 1, 0.0, search_space=space,
                   value_selections=selections)

    # 975 choices between two values in turn end one apart; 489 / 486 is not a rotation.
    two_values = selection_table([counted({"update_epochs": [488, 487]}), counted({"update_epochs": [489, 486]})])
    assert two_values[2] == "| update_epochs | 1,950 (100.0%) | 0: 977, 1: 973 |"
    assert two_values[-1] == "Pooled over 2 runs. Runs that credited every value equally often, to within one " \
                             "(a strict rotation): 1 of 2."
    nine_values = selection_table([counted({"lr": [27, 27, 27], "vf": [27, 27, 27]}),
                                   counted({"lr": [28, 27, 27], "vf": [27, 27, 27]}),
                                   counted({"lr": [28, 27, 26], "vf": [27, 27, 27]})])
    assert nine_values[-1].endswith("(a strict rotation): 2 of 3.")


def test_settings_in_force_give_each_clusters_longest_held_value_by_hand():
    space = {"learning_rate": [1e-3, 2e-3], "vf_coef": [0.5, 1.0]}
    steps = np.arange(1.0, 5.0)
    run = Run("p", "pybullet", "A", "ultho", 5.0, 10, 2, 4, 1234.5, search_space=space, series={
        "hparams/learning_rate": np.column_stack([steps, [1e-3, 2e-3, 2e-3, 2e-3]]),
        "hparams/vf_coef": np.column_stack([steps, [0.5, 0.5, 1.0, 1.0]])})  # a tie: the smaller value
    assert settings_in_force([run])[2] == "| A | 2 | 0.002 (75%) | 0.5 (50%) | 1,234 |"
    assert settings_in_force([Run("p", "pybullet", "A", "ultho", 5.0, 10, 2, 4, 1.0, search_space=space)]) == []


def test_labels_name_the_credit_the_rotation_and_the_settings_fixed_runs_differ_in():
    """The authors' PyBullet configuration beside the paper's: PPO at 5 epochs is its own method (PPO's runs
    disagree on update_epochs, and 5 is not the script's default), PPO at the defaults keeps the plain name."""
    paper = {"learning_rate": [2e-4, 5e-4, 7e-4], "minibatch_size": [64, 128, 256], "vf_coef": [0.25, 0.5, 1.0]}
    epochs = {"update_epochs": [10, 5]}

    def made(kind, settings=None, space=None, variant="ucb:level:none", utility="value"):
        return Run("p", "pybullet", "HopperBulletEnv-v0", kind, 5.0 if space else None, 10 if space else None, 1, 1,
                   1.0, search_space=space, variant=variant, utility=utility,
                   settings={"seed": 7, "update_epochs": 10, "learning_rate": 2e-4, **(settings or {})})

    runs = [made("ppo"), made("ppo", {"update_epochs": 5, "seed": 3}), made("ultho", space=paper),
            made("ultho", {"update_epochs": 5}, space=epochs, utility="authors-return"),
            made("ultho", space=epochs, variant="round-robin:level:none"),
            made("ultho", space=paper, variant="round-robin:level:none")]
    study = Study()
    study.runs = runs
    study.label_methods()
    assert [r.label for r in runs] == [
        "PPO", "PPO, update_epochs=5", "ULTHO (c=5, W=10)", "ULTHO authors-return (c=5, W=10) on update_epochs=10/5",
        "Round robin on update_epochs=10/5", "Round robin"]
    alone = [made("ppo", {"update_epochs": 5})]  # every fixed-settings run alike: nothing to tell apart
    study.runs = alone
    study.label_methods()
    assert alone[0].label == "PPO"

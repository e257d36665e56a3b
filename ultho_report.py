"""The paper's figures and tables from ULTHO run directories, in one command.

Reads every run directory below the given paths (TensorBoard events through tensorboard's own reader, or the
``scalars.csv`` of an exported study, ``summary.json``, Relay-ULTHO's ``relay.json`` and ``sweep.py``'s
``sweep.json``), groups the runs by benchmark, environment and method (PPO, ULTHO per (c, W), Relay-ULTHO) and
writes PNG figures plus one ``report.md`` that shows them with the tables:

1. learning curves per environment (mean and standard deviation over seeds, one line per method);
2. per-environment scores: the final score (mean return of the last 100 training episodes) and the
   evaluation score, mean and 95% interval over seeds;
3. the aggregate table: score per method, mean and IQM with 95% stratified-bootstrap intervals over seeds and
   environments (Agarwal et al. 2021), over the environments every method in the table covers; also
   ``aggregate.csv``. Scores are normalized with fixed reference scores, never with the runs present;
4. sample efficiency: the environment steps until a run's running score first reaches a threshold;
5. the decision process: cumulative share of each cluster among the selections, share of each value within
   its cluster, and each cluster's utility and upper confidence bound over training;
6. robustness: the score at every (c, W) of each environment.

``--export-data DIR`` also writes a compact copy of the study (every ``summary.json``, ``relay.json`` and
``sweep.json``, and each run's curves as ``scalars.csv`` instead of its event files) from which the same
report can be redrawn: ``python ultho_report.py DIR --out ...``.

    python ultho_report.py runs/ --out report/

This file is the command: its arguments, and report.md and aggregate.csv put together from the sections of
the ``ultho_reporting`` package beside it, which does the reading, the statistics and the figures.
"""

import argparse
import csv
import math
import os
import sys

from ultho_reporting.export import export_data, ignored_by_git
from ultho_reporting.references import BENCHMARKS
from ultho_reporting.references import normalized as normalized  # callers that import it from here: test_sac_dmc.py
from ultho_reporting.runs import Study, catch_tensorboard_damage
from ultho_reporting.sections import AGGREGATE_COLUMNS, Options, benchmark_section, missing_section
from ultho_runs import print_error

PROG = "ultho_report.py"


def write_report(study: Study, args: argparse.Namespace) -> None:
    """report.md, led by the command line that drew it, and aggregate.csv, into ``args.out``."""
    out = args.out
    os.makedirs(out, exist_ok=True)
    options = Options(out=out, seed=args.seed, reps=args.reps, solve_threshold=args.solve_threshold,
                      solve_window=args.solve_window, per_run=args.per_run)
    benchmarks = [b for b in BENCHMARKS if any(r.benchmark == b for r in study.runs)]
    lines = ["# ULTHO report", "",
             f"`python ultho_report.py {' '.join(args.paths)} --out {out} --seed {args.seed} --reps {args.reps}"
             f" --solve-threshold {args.solve_threshold:g} --solve-window {args.solve_window}"
             f"{'' if args.per_run else ' --no-per-run'}{' --allow-missing' if args.allow_missing else ''}`: "
             f"{len(study.runs)} runs ({', '.join(BENCHMARKS[b] for b in benchmarks)}).", ""]
    rows: list[dict] = []
    for benchmark in benchmarks:
        section, section_rows = benchmark_section(study, benchmark, options)
        lines += section
        rows += section_rows
    lines += missing_section(study)
    with open(os.path.join(out, "aggregate.csv"), "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=AGGREGATE_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    with open(os.path.join(out, "report.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


class OneLineParser(argparse.ArgumentParser):
    def error(self, message: str) -> None:
        print_error(PROG, message)
        self.exit(2)


def main(argv: list[str] | None = None) -> None:
    parser = OneLineParser(
        prog=PROG, description=__doc__.replace("``", "").split("\n    python")[0],
        epilog="examples:\n  python ultho_report.py runs/ --out report/      # then open report/report.md\n"
               "  python ultho_report.py sweeps/procgen/ runs/my_run --out report/ --seed 1 --no-per-run\n"
               "  python ultho_report.py runs/sweep-minigrid --out results/minigrid \\\n"
               "      --export-data results/minigrid/data\n"
               "\nUnreadable or missing run files are named in one warning each on stderr and skipped.",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("paths", nargs="+", metavar="PATH",
                        help="run directories, relay directories, sweep directories, or folders holding them")
    parser.add_argument("--out", default="report", help="output directory for report.md, aggregate.csv and the "
                        "PNG figures (default: report)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the bootstrap: the same seed gives the same "
                        "intervals (default: 0)")
    parser.add_argument("--reps", type=int, default=50_000, help="bootstrap resamples (default: 50000, as rliable)")
    parser.add_argument("--no-per-run", dest="per_run", action="store_false", help="skip the per-run decision "
                        "figures (one PNG per ULTHO run; the aggregated ones stay)")
    parser.add_argument("--solve-threshold", type=float, default=0.9, metavar="SCORE",
                        help="the score (on the aggregate table's scale) a run must reach to count as solved in the "
                             "sample-efficiency table (default: 0.9, e.g. MiniGrid return 0.9)")
    parser.add_argument("--solve-window", type=int, default=5, metavar="N",
                        help="logged iterations the running score averages (default: 5)")
    parser.add_argument("--allow-missing", action="store_true", help="draw a partial report when a sweep, relay or "
                        "study refers to runs that are not there (default: stop, naming the first one)")
    parser.add_argument("--export-data", metavar="DIR", help="also write a compact copy of the study to DIR "
                        "(summaries, relay and sweep indexes, each run's curves as scalars.csv), enough to redraw "
                        "the report")
    args = parser.parse_args(argv)
    for path in args.paths:
        if not os.path.exists(path):
            parser.error(f"no such path: {path}")
    if args.reps < 1:
        parser.error(f"--reps must be positive, got {args.reps}")
    if args.solve_window < 1:
        parser.error(f"--solve-window must be positive, got {args.solve_window}")
    if not math.isfinite(args.solve_threshold):
        parser.error(f"--solve-threshold must be a finite number, got {args.solve_threshold}")
    if args.export_data and os.path.exists(args.export_data) and os.listdir(args.export_data):
        parser.error(f"--export-data {args.export_data}: the folder exists and is not empty")
    names = [os.path.basename(os.path.realpath(p).rstrip(os.sep)) for p in args.paths]
    if args.export_data and len(set(names)) != len(names):
        parser.error(f"--export-data: the paths {' '.join(args.paths)} share a folder name")

    catch_tensorboard_damage()

    study = Study()
    study.discover(args.paths)
    if study.absent and not args.allow_missing:
        more = f" and {len(study.absent) - 1} more" if len(study.absent) > 1 else ""
        parser.error(f"missing run {study.absent[0]}{more}; --allow-missing draws a partial report")
    for line in study.warnings:
        print(f"{PROG}: warning: {line}", file=sys.stderr)
    if not study.runs and not study.missing:
        parser.error(f"no run found below {', '.join(args.paths)} (no summary.json, relay.json or sweep.json)")
    study.normalize()
    study.label_methods()
    write_report(study, args)
    print(f"{PROG}: wrote {os.path.join(args.out, 'report.md')}", file=sys.stderr)
    if args.export_data:
        size = export_data(study, args.paths, args.export_data)
        print(f"{PROG}: wrote {size / 1e6:.1f} MB of study data to {args.export_data}", file=sys.stderr)
        if ignored := ignored_by_git(args.export_data):
            print(f"{PROG}: warning: git ignores {len(ignored)} of the exported files (e.g. {ignored[0]}): a commit "
                  "would leave them out", file=sys.stderr)


if __name__ == "__main__":
    main()

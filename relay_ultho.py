"""Relay-ULTHO (Algorithm 2 of Yuan et al., ICCV 2025) in one command, for any ppo_ultho_*.py script.

A full ULTHO run (or an existing one, ``--from``) names the cluster of interest (COI, selected most often)
and the neglected cluster of interest (NOI, selected least often among the other clusters; ties go to the
earliest cluster in the search space, so the two differ even when a bandit chose its clusters in strict
rotation). ULTHO then runs twice more from scratch
with the same seed and settings, once searching only the COI and once only the NOI; the better of the two by
final score is the Relay-ULTHO result, for a budget of three runs. ``relay.json`` in the relay directory
records all of it and is rewritten atomically as the runs finish.

The tool is restartable: killed at any point and started again with the same arguments, it skips every run
that has its ``summary.json``, resumes an interrupted one from its ``checkpoint.pt`` and starts afresh one
that was killed before its first checkpoint (the run-directory conventions of ``ultho_runs.py``).

With ``--track`` the runs it starts are mirrored to Weights & Biases, all in one W&B group: the relay directory's
name unless ``--wandb-group`` says otherwise (sweep.py gives its own, so that a sweep is one group).
"""

import argparse
import hashlib
import json
import os
import shutil
import sys
from typing import Callable, Optional, Sequence, TextIO

from ultho_bandit import clusters_of_interest, format_value
from ultho_runs import (RunFailed, UsageError, add_tracking_options, atomic_write_json, check_script_args, complete_run,
                        flag_values, parse_split_args, print_error, read_json, relative_to, resolve_script,
                        tracking_flags, without_flag)

TOOL = "relay_ultho.py"
RELAY_FORMAT = 1


def cluster_item(cluster: str, user_items: Optional[list[str]], search_space: dict[str, list]) -> str:
    """The --ultho-clusters item searching only ``cluster``: the bare name (the benchmark's values) unless
    the user gave explicit values, which are then taken from the full run's search space."""
    if user_items is None or cluster in user_items:
        return cluster
    return f"{cluster}=" + ",".join(format_value(v) for v in search_space[cluster])


def default_relay_dir(script: str, script_args: list[str], from_run: Optional[str]) -> str:
    """runs/relay__<script>__<env>__<seed>__<hash of the arguments>: the same arguments find the same relay."""
    env = (flag_values(script_args, "--env-id") or ["default"])[0].replace("/", "-")
    seed = (flag_values(script_args, "--seed") or ["default"])[0]
    key = json.dumps([os.path.basename(script), script_args, from_run and os.path.abspath(from_run)])
    stem = os.path.splitext(os.path.basename(script))[0]
    return os.path.join("runs", f"relay__{stem}__{env}__{seed}__{hashlib.sha1(key.encode()).hexdigest()[:8]}")


def checked_full_summary(summary: dict, where: str) -> tuple[str, str]:
    """(COI, NOI) of a finished full ULTHO run; refuses a run that cannot seed a relay."""
    bandit = summary.get("bandit")
    if bandit is None:
        raise UsageError(f"{where} is a --no-ultho run: Relay-ULTHO needs a full ULTHO run")
    if len(bandit["search_space"]) < 2:
        raise UsageError(f"{where} searched one cluster ({', '.join(bandit['search_space'])}): Relay-ULTHO "
                         "needs a full run over at least two clusters, since its COI and NOI would coincide")
    if sum(bandit["selections"].values()) == 0:
        if summary.get("diverged"):
            raise UsageError(f"{where} diverged at iteration {summary['diverged']['iteration']}, before crediting "
                             "any selection: it says nothing about its clusters")
        raise UsageError(f"{where} credited no selection (selections {bandit['selections']}): it says nothing "
                         "about its clusters; give it more than one iteration")
    # Recomputed from the selections rather than read: clusters_of_interest always gives two different
    # clusters, which a summary's stored coi and noi need not be.
    return clusters_of_interest(bandit["selections"])


def relay(script: str, script_args: list[str], relay_dir: str, from_run: Optional[str] = None,
          max_retries: int = 2, run_flags: Sequence[str] = (), output: Optional[TextIO] = None,
          log: Callable[[str], None] = print) -> dict:
    """Runs Relay-ULTHO to the end, reusing whatever is already done in ``relay_dir``; returns relay.json.

    ``run_flags`` go to every command but not into relay.json (``--quiet``, the W&B flags of --track). Raises
    UsageError for bad input (before anything is written) and RunFailed for a run that did not finish.
    """
    check_script_args(script_args)
    script_path = resolve_script(script)
    user_items = flag_values(script_args, "--ultho-clusters")
    if user_items is not None and len(user_items) < 2:
        raise UsageError(f"--ultho-clusters {' '.join(user_items)}: Relay-ULTHO needs at least two clusters, "
                         "since with one its COI and NOI would coincide")
    if max_retries < 0:
        raise UsageError(f"--max-retries must be >= 0, got {max_retries}")
    run_args = [*script_args, *run_flags]
    full_summary = None
    if from_run is not None:
        full_summary = read_json(os.path.join(from_run, "summary.json"))
        if full_summary is None:
            raise UsageError(f"--from {from_run}: no summary.json there (finish it first with --resume)")
        if full_summary.get("script") != os.path.splitext(os.path.basename(script))[0]:
            raise UsageError(f"--from {from_run}: a {full_summary.get('script')} run, not one of {script}")
        for flag, key in (("--env-id", "env_id"), ("--seed", "seed")):
            given = flag_values(script_args, flag)
            if given and given[0] != str(full_summary[key]):
                raise UsageError(f"--from {from_run}: its {key} is {full_summary[key]}, not {flag} {given[0]}")
            if not given:  # the relay runs take the reused run's environment and seed
                run_args += [flag, str(full_summary[key])]
        checked_full_summary(full_summary, f"--from {from_run}")

    full_run = from_run if from_run is not None else os.path.join(relay_dir, "full")
    record_path = os.path.join(relay_dir, "relay.json")
    record = read_json(record_path)
    if record is not None and (record["script"], record["script_args"], record["full_run"]) != (
            os.path.basename(script), script_args, relative_to(full_run, relay_dir)):
        raise UsageError(f"{relay_dir} holds a relay of other arguments: {record['script']} "
                         f"{' '.join(record['script_args'])} from {record['full_run']}")
    created = not os.path.exists(relay_dir)
    os.makedirs(relay_dir, exist_ok=True)
    if record is None:
        record = {"format": RELAY_FORMAT, "script": os.path.basename(script), "script_args": script_args,
                  "env_id": None, "seed": None, "status": "running", "full_run": relative_to(full_run, relay_dir),
                  "coi": None, "noi": None, "coi_run": None, "noi_run": None,
                  "final_scores": {"full": None, "coi": None, "noi": None},
                  "winner": None, "winner_run": None, "final_score": None, "total_timesteps": None}
        atomic_write_json(record_path, record)

    try:
        if full_summary is None:
            log(f"[relay] full ULTHO run in {full_run}")
            full_summary, _ = complete_run(script_path, run_args, full_run, max_retries, output, log)
    except RunFailed as err:
        if err.exit_status == 2 and created:
            shutil.rmtree(relay_dir)  # the script named the bad argument; leave nothing behind
        raise
    coi, noi = checked_full_summary(full_summary, f"full run {full_run}")
    record.update(env_id=full_summary["env_id"], seed=full_summary["seed"], coi=coi, noi=noi)
    record["final_scores"]["full"] = full_summary["final_score"]
    atomic_write_json(record_path, record)

    summaries = {"full": full_summary}
    for role, cluster in (("coi", coi), ("noi", noi)):
        run_dir = os.path.join(relay_dir, role)
        args = [*without_flag(run_args, "--ultho-clusters"), "--ultho-clusters",
                cluster_item(cluster, user_items, full_summary["bandit"]["search_space"])]
        log(f"[relay] {role.upper()} run ({cluster} only) in {run_dir}")
        summaries[role], _ = complete_run(script_path, args, run_dir, max_retries, output, log)
        record[f"{role}_run"] = relative_to(run_dir, relay_dir)
        record["final_scores"][role] = summaries[role]["final_score"]
        atomic_write_json(record_path, record)

    # A run that diverged (its summary says where) ended with a network that is not finite, and a run in which no
    # episode ended has no final score: each loses to a run without that fault (ties go to the COI).
    def score(role: str) -> tuple[bool, float]:
        value = summaries[role]["final_score"]
        return summaries[role].get("diverged") is None, float("-inf") if value is None else value

    winner = "coi" if score("coi") >= score("noi") else "noi"
    record.update(status="done", winner=winner, winner_run=record[f"{winner}_run"],
                  final_score=summaries[winner]["final_score"],
                  total_timesteps=sum(s["global_step"] for s in summaries.values()))
    atomic_write_json(record_path, record)
    def scored(role: str) -> str:
        diverged = summaries[role].get("diverged")
        return f"{summaries[role]['final_score']}" + (f" (diverged at step {diverged['global_step']})" if diverged
                                                      else "")

    log(f"[relay] done: COI {coi} scored {scored('coi')}, NOI {noi} scored {scored('noi')}; winner "
        f"{winner.upper()}, {record['total_timesteps']} steps in all; {record_path}")
    return record


def parse_args(argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    """(the tool's options, the script's arguments after --)."""
    parser = argparse.ArgumentParser(
        prog=TOOL,
        usage=f"{TOOL} [-h] [--from RUN_DIR] [--relay-dir DIR] [--max-retries N] [--quiet] [--track "
              "[--wandb-project-name NAME] [--wandb-entity NAME] [--wandb-group NAME]] SCRIPT [-- SCRIPT_ARGS...]",
        formatter_class=argparse.RawDescriptionHelpFormatter,
        description="Relay-ULTHO (Algorithm 2): a full ULTHO run, then ULTHO on its most-selected cluster (COI) "
                    "and on its least-selected cluster (NOI) alone, same seed and settings; the better of the two "
                    "by final score is the result. Writes relay.json in the relay directory. Run it again with the "
                    "same arguments after a crash: finished runs are kept, an interrupted one resumes from its "
                    "checkpoint.",
        epilog="examples:\n"
               "  python relay_ultho.py ppo_ultho_procgen.py -- --env-id starpilot --seed 1\n"
               "  python relay_ultho.py ppo_ultho_minigrid.py --from runs/<a finished ULTHO run>\n"
               "  python relay_ultho.py ppo_ultho_minigrid.py --relay-dir runs/relay-doorkey -- "
               "--ultho-c 1 --ultho-window 50\n"
               "  python relay_ultho.py ppo_ultho_minigrid.py --relay-dir runs/relay-doorkey --track   "
               "# W&B group relay-doorkey\n"
               "\nThe tool sets the script's --runs-dir, --run-name and --resume itself; --no-ultho and --init-from "
               "are refused; --track and --wandb-* go before --, to the tool, which passes them on.",
    )
    parser.add_argument("script", help="the training script, e.g. ppo_ultho_minigrid.py")
    parser.add_argument("--from", dest="from_run", metavar="RUN_DIR",
                        help="reuse this finished full ULTHO run instead of starting one (its env id and seed are "
                             "used)")
    parser.add_argument("--relay-dir", metavar="DIR", help="where the runs and relay.json go (default: "
                        "runs/relay__<script>__<env>__<seed>__<hash of the arguments>)")
    parser.add_argument("--max-retries", type=int, default=2, metavar="N",
                        help="times a failed or interrupted run is resumed from its checkpoint (default: 2)")
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors (also passed to the script)")
    add_tracking_options(parser, "the runs the relay starts (not a --from run)", "the relay directory's name")
    return parse_split_args(parser, argv)


def main(argv: list[str]) -> int:
    try:
        args, script_args = parse_args(argv)
        relay_dir = args.relay_dir or default_relay_dir(args.script, script_args, args.from_run)
        tracking = tracking_flags(args, script_args, os.path.basename(os.path.abspath(relay_dir)))
        relay(args.script, script_args, relay_dir, args.from_run, args.max_retries,
              run_flags=[*(["--quiet"] if args.quiet else []), *tracking],
              log=(lambda line: None) if args.quiet else (lambda line: print(line, flush=True)))
    except UsageError as err:
        print_error(TOOL, err)
        return 2
    except RunFailed as err:
        if err.exit_status != 2:  # with 2 the script has printed the one line naming the bad argument
            print_error(TOOL, f"{err}; run the same command again to resume it")
        return 2 if err.exit_status == 2 else 1
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

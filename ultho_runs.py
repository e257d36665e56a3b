"""The tools' conventions for run directories and command lines: what relay_ultho.py, sweep.py,
hpo_baselines.py and ultho_report.py share.

A run directory is what one process of a ``ppo_ultho_*.py`` script writes: ``checkpoint.pt`` while it runs
and ``summary.json`` once it has finished. Its state follows from those two files alone (:func:`run_state`),
which makes every tool restartable: a finished run is never repeated, an interrupted one continues with
``--resume``, one that never checkpointed starts afresh (:func:`complete_run`). The tools' own records
(relay.json, sweep.json, study.json) are JSON, written atomically (:func:`atomic_write_json`).

A tool's command line is its own options, then ``--``, then the script's arguments (:func:`parse_split_args`).
Bad input is one line ``<tool>.py: error: <message>`` on stderr and exit status 2 (:class:`UsageError`,
:func:`print_error`).

The four scripts do not import this module: each stays one self-contained file with its own copies of the
few lines it needs (its ``UsageError``, its atomic write).
"""

import argparse
import contextlib
import io
import json
import os
import shutil
import subprocess
import sys
from typing import Callable, Literal, Optional, TextIO

OWNED_FLAGS = ("--no-ultho", "--run-name", "--runs-dir", "--resume", "--init-from")
"""Script flags the tools set themselves; a user passing one would break the resume logic."""

RunState = Literal["done", "resumable", "fresh"]


# ---------------------------------------------------------------------- errors and command lines
class UsageError(Exception):
    """Bad input: one line on stderr, exit status 2, nothing started."""


def print_error(tool: str, message: object) -> None:
    """The one-line error of every tool: ``<tool>: error: <message>`` on stderr, ``tool`` being its file name."""
    print(f"{tool}: error: {message}", file=sys.stderr)


def parse_split_args(parser: argparse.ArgumentParser, argv: list[str]) -> tuple[argparse.Namespace, list[str]]:
    """(the tool's options before ``--``, the script's arguments after it). argparse's usage-and-message
    error becomes a UsageError holding the message alone, for the one-line convention."""
    split = argv.index("--") if "--" in argv else len(argv)
    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            return parser.parse_args(argv[:split]), argv[split + 1:]
    except SystemExit as exit_:
        if exit_.code in (0, None):
            raise
        lines = err.getvalue().strip().splitlines()
        raise UsageError(lines[-1].split("error: ", 1)[-1] if lines else "invalid arguments") from None


def flag_values(args: list[str], flag: str) -> Optional[list[str]]:
    """The values of the last ``flag`` in a script's argument list (``--flag a b`` or ``--flag=a``), or None."""
    found = None
    for k, token in enumerate(args):
        if token == flag:
            found = []
            for value in args[k + 1:]:
                if value.startswith("--"):
                    break
                found.append(value)
        elif token.startswith(flag + "="):
            found = [token[len(flag) + 1:]]
    return found


def without_flag(args: list[str], flag: str) -> list[str]:
    """``args`` with every ``flag`` and its values removed."""
    out, skipping = [], False
    for token in args:
        if token == flag:
            skipping = True
        elif token.startswith(flag + "="):
            skipping = False
        elif skipping and not token.startswith("--"):
            continue
        else:
            skipping = False
            out.append(token)
    return out


def check_script_args(args: list[str]) -> None:
    """Refuses script arguments that set one of :data:`OWNED_FLAGS`."""
    for token in args:
        for flag in OWNED_FLAGS:
            if token == flag or token.startswith(flag + "="):
                raise UsageError(f"{flag} is set by the tool itself; remove it from the arguments after --")


def resolve_script(script: str) -> str:
    """A script path as given, else the file of that name beside the tools (the repository root); absolute."""
    for candidate in (script, os.path.join(os.path.dirname(os.path.abspath(__file__)), script)):
        if os.path.isfile(candidate):
            return os.path.abspath(candidate)
    raise UsageError(f"script {script}: no such file")


def script_command(script_path: str, args: list[str], run_dir: str, resume: bool) -> list[str]:
    """The command that starts ``run_dir`` afresh, or continues it from its checkpoint."""
    place = ["--resume", run_dir] if resume else ["--runs-dir", os.path.dirname(run_dir) or ".",
                                                  "--run-name", os.path.basename(run_dir)]
    return [sys.executable, script_path, *args, *place]


# ---------------------------------------------------------------------- run directories
def run_state(run_dir: str) -> RunState:
    """done: summary.json exists (a run that diverged included: its summary says so); resumable: checkpoint.pt
    but no summary; fresh: neither (never started, or killed before its first checkpoint, so nothing in it is
    worth keeping)."""
    if os.path.isfile(os.path.join(run_dir, "summary.json")):
        return "done"
    if os.path.isfile(os.path.join(run_dir, "checkpoint.pt")):
        return "resumable"
    return "fresh"


class RunFailed(Exception):
    """A run that did not finish within its retries: the script's last exit status, processes started."""

    def __init__(self, message: str, exit_status: int, attempts: int):
        super().__init__(message)
        self.exit_status, self.attempts = exit_status, attempts


def complete_run(script_path: str, args: list[str], run_dir: str, max_retries: int,
                 output: Optional[TextIO] = None, log: Callable[[str], None] = lambda line: None) -> tuple[dict, int]:
    """Brings ``run_dir`` to done and returns (its summary, processes started). A run already done starts
    nothing; an interrupted or failed one continues from its checkpoint (``--resume``), at most
    ``max_retries`` times after the first attempt. A script's bad-input exit (2) is not retried, nor a run
    that diverged: its script exits 1 after writing a summary that records the divergence (``diverged``), so
    it is done, and resuming it would only replay the same divergence."""
    attempts, status = 0, None
    while True:
        state = run_state(run_dir)
        if state == "done":
            return read_json(os.path.join(run_dir, "summary.json")), attempts
        if attempts > max_retries:
            raise RunFailed(f"{run_dir} failed {attempts} time(s), last exit status {status}", status, attempts)
        if state == "fresh" and os.path.exists(run_dir):
            shutil.rmtree(run_dir)
        command = script_command(script_path, args, run_dir, resume=state == "resumable")
        log(("resuming " if state == "resumable" else "starting ") + " ".join(command[1:]))
        attempts += 1
        status = subprocess.run(command, stdout=output, stderr=output).returncode
        if status == 2:
            raise RunFailed(f"{os.path.basename(script_path)} refused the arguments for {run_dir}", 2, attempts)


def relative_to(path: str, base: str) -> str:
    """``path`` relative to ``base`` when inside it, else absolute: how relay.json and study.json name runs."""
    path, base = os.path.abspath(path), os.path.abspath(base)
    return os.path.relpath(path, base) if os.path.commonpath([path, base]) == base else path


# ---------------------------------------------------------------------- JSON records
def atomic_write_json(path: str, obj: dict) -> None:
    """Readers never see a half-written file: write a sibling, fsync, rename over."""
    tmp = f"{path}.tmp"
    with open(tmp, "w") as f:
        f.write(json.dumps(obj, indent=2, allow_nan=False) + "\n")
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)


def read_json(path: str) -> Optional[dict]:
    """The file's JSON, or None when there is no such file."""
    try:
        with open(path) as f:
            return json.load(f)
    except FileNotFoundError:
        return None

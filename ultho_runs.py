"""The tools' conventions for run directories and command lines: what relay_ultho.py, sweep.py,
hpo_baselines.py and ultho_report.py share.

A run directory is what one process of a ``ppo_ultho_*.py`` script writes: ``checkpoint.pt`` while it runs
and ``summary.json`` once it has finished. Its state follows from those two files alone (:func:`run_state`),
which makes every tool restartable: a finished run is never repeated, an interrupted one continues with
``--resume``, one that never checkpointed starts afresh (:func:`complete_run`). The tools' own records
(relay.json, sweep.json, study.json) are JSON, written atomically (:func:`atomic_write_json`).

A tool's command line is its own options, then ``--``, then the script's arguments (:func:`parse_split_args`).
Bad input is one line ``<tool>.py: error: <message>`` on stderr and exit status 2 (:class:`UsageError`,
:func:`print_error`). With ``--track`` a tool passes the scripts' W&B flags to every run it starts, all of one
study in one W&B group (:func:`add_tracking_options`, :func:`tracking_flags`).

The four scripts do not import this module: each stays one self-contained file with its own copies of the
few lines it needs (its ``UsageError``, its atomic write).
"""

import argparse
import ast
import contextlib
import importlib.util
import io
import json
import netrc
import os
import shutil
import subprocess
import sys
import urllib.parse
from typing import Callable, Literal, Optional, TextIO

OWNED_FLAGS = ("--no-ultho", "--run-name", "--runs-dir", "--resume", "--init-from")
"""Script flags the tools set themselves; a user passing one would break the resume logic."""

TRACKING_FLAGS = ("--track", "--wandb-project-name", "--wandb-entity", "--wandb-group")
"""The scripts' W&B flags: a tool sets them itself on every run it starts, so that a study's runs share a group."""
WANDB_NAME_FORBIDDEN = "/\\#?%:"
"""Characters W&B refuses in a project, entity or group name (the scripts' own check)."""

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


# ---------------------------------------------------------------------- W&B tracking
def add_tracking_options(parser: argparse.ArgumentParser, runs: str, group: str) -> None:
    """The tools' --track, --wandb-project-name, --wandb-entity and --wandb-group: the scripts' flags, which the
    tool passes on. ``runs``: what the tool starts, for the help; ``group``: the default W&B group, for the help."""
    tracking = parser.add_argument_group("tracking (Weights & Biases)")
    tracking.add_argument("--track", action="store_true",
                          help=f"mirror {runs} to Weights & Biases (config, code, every TensorBoard scalar), all in "
                               "one W&B group; needs `wandb login`, or WANDB_MODE=offline to log locally for "
                               "`wandb sync` later")
    tracking.add_argument("--wandb-project-name", default="ultho", metavar="NAME",
                          help="the W&B project of --track (default: ultho)")
    tracking.add_argument("--wandb-entity", metavar="NAME",
                          help="the W&B team or user of --track (default: your W&B default entity)")
    tracking.add_argument("--wandb-group", metavar="NAME", help=f"the W&B group of --track (default: {group})")


def tracking_flags(args: argparse.Namespace, script_args: list[str], default_group: str,
                   check_login: bool = True) -> list[str]:
    """The script flags that put every run the tool starts in W&B, in ``args.wandb_group`` or else
    ``default_group`` (the study's folder name); [] without --track. Refuses the W&B flags after -- (the tool
    sets them), names W&B would refuse, and with ``check_login`` a machine where W&B has no key: each run would
    exit 2, so nothing is started."""
    for token in script_args:
        for flag in TRACKING_FLAGS:
            if token == flag or token.startswith(flag + "="):
                raise UsageError(f"{flag} after --: put --track and the --wandb-* options before --; the tool passes "
                                 "them to every run it starts, with one W&B group")
    if not args.track:
        if args.wandb_entity is not None or args.wandb_group is not None:
            raise UsageError("--wandb-entity and --wandb-group name where --track logs: add --track")
        return []
    group = args.wandb_group if args.wandb_group is not None else default_group
    rule = "W&B names are 1 to 128 characters without / \\ # ? % :"
    for flag, name in (("--wandb-project-name", args.wandb_project_name), ("--wandb-entity", args.wandb_entity),
                       ("--wandb-group", args.wandb_group)):
        if name is not None and not is_wandb_name(name):
            raise UsageError(f"{flag} {name!r}: {rule}")
    if not is_wandb_name(group):
        raise UsageError(f"the W&B group is by default the folder's name, {group!r}, which W&B refuses ({rule}); "
                         "give --wandb-group NAME")
    if importlib.util.find_spec("wandb") is None:
        raise UsageError("--track needs the wandb package: pip install -r requirements.txt")
    if check_login and os.environ.get("WANDB_MODE", "").lower() not in ("offline", "disabled", "dryrun") \
            and not wandb_logged_in():
        raise UsageError("--track: no W&B login on this machine: run `wandb login`, or set WANDB_MODE=offline to "
                         "log locally and `wandb sync` the runs later")
    entity = ["--wandb-entity", args.wandb_entity] if args.wandb_entity is not None else []
    return ["--track", "--wandb-project-name", args.wandb_project_name, *entity, "--wandb-group", group]


def is_wandb_name(name: str) -> bool:
    return 0 < len(name) <= 128 and not set(name) & set(WANDB_NAME_FORBIDDEN)


def wandb_logged_in() -> bool:
    """Whether W&B finds an API key: WANDB_API_KEY, or the netrc entry `wandb login` writes for its host (the
    scripts' own test, so that the tool refuses exactly what its runs would)."""
    if os.environ.get("WANDB_API_KEY"):
        return True
    host = urllib.parse.urlparse(os.environ.get("WANDB_BASE_URL", "https://api.wandb.ai")).hostname
    try:
        return netrc.netrc(os.environ.get("NETRC")).authenticators(host) is not None
    except (OSError, netrc.NetrcParseError):
        return False


# ---------------------------------------------------------------------- a script's literals
def script_literals(path: str) -> tuple[dict, dict]:
    """A training script's literal module-level constants (SEARCH_SPACE, TUNABLE, ...) and the literal defaults of
    its Args fields, read from its source: importing it would start torch and its environments. Values that are not
    literals are left out."""
    with open(path, encoding="utf-8") as f:
        tree = ast.parse(f.read())
    constants, defaults = {}, {}
    for node in tree.body:
        if isinstance(node, ast.Assign) and len(node.targets) == 1 and isinstance(node.targets[0], ast.Name):
            with contextlib.suppress(ValueError):
                constants[node.targets[0].id] = ast.literal_eval(node.value)
        elif isinstance(node, ast.ClassDef) and node.name == "Args":
            for item in node.body:
                if isinstance(item, ast.AnnAssign) and isinstance(item.target, ast.Name) and item.value:
                    with contextlib.suppress(ValueError):
                        defaults[item.target.id] = ast.literal_eval(item.value)
    return constants, defaults


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

"""A compact copy of a study, from which the same report redraws (``ultho_report.py --export-data DIR``).

It keeps what the report read and nothing else: every ``summary.json``, ``relay.json``, ``study.json`` and
``sweep.json`` as it is, and each run's curves (the return, ``hparams/*`` and the cluster-level ``ultho/*``
series) as a ``scalars.csv`` instead of its TensorBoard event files and checkpoints. The results folders
commit such copies as their ``data/``.
"""

import csv
import json
import math
import os
import shutil
import subprocess

import numpy as np

from ultho_reporting.runs import SCALARS_CSV, Study


def export_data(study: Study, roots: list[str], out: str) -> int:
    """Copies what the report read into ``out``: JSON files as they are, each run's curves as scalars.csv.

    Each root keeps its own folder (its base name) with its layout below, so sweep.json's and relay.json's
    relative paths still hold; a relay's absolute ``full_run`` inside a root becomes relative. Returns the
    number of bytes written.
    """
    roots = [os.path.realpath(r) for r in roots]
    names = [os.path.basename(r.rstrip(os.sep)) or "root" for r in roots]
    if len(set(names)) != len(names):
        raise ValueError(f"--export-data: the paths {', '.join(roots)} share a folder name")

    def target(path: str) -> str | None:
        real = os.path.realpath(path)
        for root, name in zip(roots, names):
            if real == root or real.startswith(root + os.sep):
                return os.path.normpath(os.path.join(out, name, os.path.relpath(real, root)))
        return None

    written = 0
    for path in dict.fromkeys(study.files):
        destination = target(path)
        if destination is None:
            continue
        os.makedirs(os.path.dirname(destination), exist_ok=True)
        if os.path.basename(path) == "relay.json":
            with open(path) as f:
                relay = json.load(f)
            if os.path.isabs(relay.get("full_run") or "") and (full := target(relay["full_run"])):
                relay["full_run"] = os.path.relpath(full, os.path.dirname(destination))
            with open(destination, "w") as f:
                json.dump(relay, f, indent=1)
        else:
            shutil.copyfile(path, destination)
        written += os.path.getsize(destination)
        run_dir = os.path.dirname(path)
        if os.path.basename(path) == "summary.json" and (series := study.read_scalars(run_dir)):
            written += write_scalars_csv(series, os.path.join(os.path.dirname(destination), SCALARS_CSV))
    return written


def ignored_by_git(folder: str) -> list[str]:
    """The files below ``folder`` that git would leave out of a commit (none outside a git work tree)."""
    files = [os.path.join(d, name) for d, _, names in os.walk(folder) for name in names]
    try:
        result = subprocess.run(["git", "-C", folder, "check-ignore", "--no-index", "--stdin"], capture_output=True,
                                text=True, input="\n".join(os.path.abspath(f) for f in files))
    except OSError:  # no git
        return []
    return result.stdout.splitlines() if result.returncode == 0 else []


def write_scalars_csv(series: dict[str, np.ndarray], path: str) -> int:
    """One row per logged step, one column per tag; float32 values (TensorBoard's) written to round-trip."""
    tags = sorted(series)
    steps = sorted({int(step) for tag in tags for step in series[tag][:, 0]})
    position = {step: i for i, step in enumerate(steps)}
    table = [[""] * len(tags) for _ in steps]
    for k, tag in enumerate(tags):
        for step, value in series[tag]:
            table[position[int(step)]][k] = "nan" if math.isnan(value) else f"{np.float32(value)!r}".removeprefix(
                "np.float32(").removesuffix(")")
    with open(path, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(["step", *tags])
        writer.writerows([[step, *row] for step, row in zip(steps, table)])
    return os.path.getsize(path)

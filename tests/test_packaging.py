"""`pip install .` gives other projects the bandit and the SB3 callback, and nothing else of the repository.

The wheel is built from this checkout with the pinned setuptools of the running environment (no build isolation:
nothing is downloaded) and installed into a fresh virtual environment, where the modules are imported from a
directory outside the repository. The callback's dependencies (SB3, torch) are not installed again: a .pth file
puts this environment's site-packages behind the fresh one's, which costs a line instead of a torch download.
"""

import os
import site
import subprocess
import sys
import zipfile

import pytest

from helpers import REPO


def run_ok(command: list[str], cwd: str) -> subprocess.CompletedProcess:
    # A clean environment: PYTHONPATH (pytest's pythonpath does not set it, a developer's shell may) would let
    # the repository's files stand in for the installed ones.
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME")}
    result = subprocess.run(command, cwd=cwd, env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, f"{' '.join(command)}:\n{result.stdout}\n{result.stderr}"
    return result


def untracked_files() -> set[str]:
    status = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=REPO,
                            capture_output=True, text=True, check=True).stdout
    return {line[3:] for line in status.splitlines() if line.startswith("??")}


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> str:
    if not os.path.exists(os.path.join(REPO, ".git")):
        pytest.skip("not a git checkout: nothing to keep clean")
    before = untracked_files()
    out = tmp_path_factory.mktemp("wheel")
    run_ok([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index",
            "--wheel-dir", str(out), REPO], cwd=str(out))
    # The build works in the checkout (build/, *.egg-info): .gitignore must hide all of it, also where an
    # earlier build left it behind.
    after = untracked_files()
    assert after == before and not [f for f in after if f.startswith("build/") or ".egg-info/" in f], after - before
    [name] = os.listdir(out)
    return str(out / name)


def test_the_wheel_holds_the_two_modules_and_requires_sb3_only_for_the_callback(wheel):
    with zipfile.ZipFile(wheel) as archive:
        names = archive.namelist()
        [metadata] = [n for n in names if n.endswith(".dist-info/METADATA")]
        requirements = [line.removeprefix("Requires-Dist: ") for line in
                        archive.read(metadata).decode().splitlines() if line.startswith("Requires-Dist: ")]
    assert sorted(n for n in names if ".dist-info/" not in n) == ["ultho_bandit.py", "ultho_sb3.py"]
    assert requirements and all(r.endswith('extra == "sb3"') for r in requirements), requirements
    assert any(r.startswith("stable-baselines3") for r in requirements), requirements


def test_installed_modules_import_from_outside_the_repository(wheel, tmp_path):
    venv = tmp_path / "venv"
    run_ok([sys.executable, "-m", "venv", str(venv)], cwd=str(tmp_path))
    python = str(venv / "bin" / "python")
    run_ok([python, "-m", "pip", "install", "--no-deps", "--no-index", "--disable-pip-version-check", wheel],
           cwd=str(tmp_path))
    elsewhere = tmp_path / "project"
    elsewhere.mkdir()

    # The bandit alone: the fresh environment has nothing but pip (and whatever venv adds).
    bandit = run_ok([python, "-c", "import ultho_bandit\n"
                     "bandit = ultho_bandit.ULTHO({'learning_rate': [1e-4, 3e-4]})\n"
                     "print(ultho_bandit.__file__, bandit.select()[0])"], cwd=str(elsewhere)).stdout.split()
    assert bandit[0].startswith(str(venv)) and bandit[1] == "learning_rate"

    # The callback, with this environment's SB3 and torch behind the fresh environment's own packages.
    [fresh_site] = (venv / "lib").glob("python*/site-packages")
    (fresh_site / "project_packages.pth").write_text("\n".join(site.getsitepackages()) + "\n")
    callback = run_ok([python, "-c", "from ultho_sb3 import ULTHOCallback\nimport ultho_sb3\n"
                       "ULTHOCallback({'n_epochs': [5, 10]})\nprint(ultho_sb3.__file__)"], cwd=str(elsewhere))
    assert callback.stdout.strip().startswith(str(venv))

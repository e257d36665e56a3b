"""What the tests of hpo_baselines.py and of the report share: tiny MiniGrid studies on a real local Ray instance."""

import os
import subprocess

from helpers import run

TOOL = "hpo_baselines.py"
SCRIPT = "ppo_ultho_minigrid.py"
STEP = 256  # one iteration: 4 envs x 64 steps; every Empty-5x5 episode (at most 100 steps) ends within two
SPACE = {"learning_rate": [1e-3, 2.5e-3, 5e-3], "minibatch_size": [32, 64, 128], "vf_coef": [0.25, 0.5, 1.0]}
SCRIPT_ARGS = ["--env-id", "MiniGrid-Empty-5x5-v0", "--num-envs", "4", "--num-steps", "64", "--minibatch-size", "64",
               "--ultho-clusters", "learning_rate", "minibatch_size=32,64,128", "vf_coef", "--eval-episodes", "2"]
RAY_TOKEN_FILE = os.path.expanduser("~/.ray/auth_token")
FLAGS = {"learning_rate": "--learning-rate", "minibatch_size": "--minibatch-size", "vf_coef": "--vf-coef"}
STUDY_FIELDS = {"format", "tool", "status", "method", "script", "script_args", "seed", "population", "samples",
                "interval", "quantile", "resample_probability", "search_space", "fixed_settings", "budget",
                "best_trial", "best_final_score", "best_settings_schedule", "max_observed_score", "exploits",
                "trials", "errors"}


def study(study_dir, *tool_args: str, total: int = 4 * STEP, env: dict | None = None) -> subprocess.CompletedProcess:
    """A study of two-iteration segments on the local Ray instance the tool starts (2 CPUs, a trial each)."""
    return run(TOOL, SCRIPT, *tool_args, "--interval", str(2 * STEP), "--study-dir", str(study_dir), "--num-cpus", "2",
               "--", *SCRIPT_ARGS, "--total-timesteps", str(total), env=env)

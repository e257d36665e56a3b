"""What the script tests share: running a script as a user would, reading back what it wrote, and feeding a
script's own network and loss a real rollout."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from ultho_bandit import ULTHO

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def run(script: str, *args: str, timeout: float = 600, env: dict | None = None) -> subprocess.CompletedProcess:
    """`python <script> <args>` from the repository root, output captured; ``env`` adds environment variables."""
    return subprocess.run([sys.executable, os.path.join(REPO, script), *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO, env=None if env is None else {**os.environ, **env})


def run_concurrently(script: str, arg_lists: list[list[str]],
                     timeout: float = 600) -> list[subprocess.CompletedProcess]:
    """`run` for every argument list at once (each start pays the torch import); results in the same order."""
    processes = [subprocess.Popen([sys.executable, os.path.join(REPO, script), *args], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True, cwd=REPO) for args in arg_lists]
    results = []
    for args, process in zip(arg_lists, processes):
        stdout, stderr = process.communicate(timeout=timeout)
        results.append(subprocess.CompletedProcess(process.args, process.returncode, stdout, stderr))
    return results


def run_ok(script: str, *args: str) -> subprocess.CompletedProcess:
    result = run(script, *args)
    assert result.returncode == 0, f"{script} failed:\n{result.stdout}\n{result.stderr}"
    return result


def kill_after_first_checkpoint(script: str, run_dir: str, *args: str, timeout: float = 300) -> None:
    """Starts a run and SIGKILLs it as soon as its first checkpoint is on disk (a crash, not a clean exit)."""
    process = subprocess.Popen([sys.executable, os.path.join(REPO, script), *args], cwd=REPO,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + timeout
    path = os.path.join(run_dir, "checkpoint.pt")
    while not os.path.exists(path) and process.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait()


def evaluation_seeds(script, monkeypatch, *evaluate_args) -> list[int]:
    """The seeds with which ``script.evaluate(*evaluate_args)`` resets its environments: a spy on the script's
    make_envs records them, while the environments and the episodes played are the real ones."""
    seeds: list[int] = []
    make_envs = script.make_envs

    def recording_make_envs(*args, **kwargs):
        envs = make_envs(*args, **kwargs)
        reset = envs.reset

        def recording_reset(*, seed=None, options=None):
            seeds.extend(np.asarray(seed).tolist())
            return reset(seed=seed, options=options)

        envs.reset = recording_reset
        return envs

    with monkeypatch.context() as patch:
        patch.setattr(script, "make_envs", recording_make_envs)
        script.evaluate(*evaluate_args)
    return seeds


def assert_diverged_and_recorded(result: subprocess.CompletedProcess, run_dir, iteration: int, setting: str,
                                 checkpoint_key: str) -> dict:
    """A run stopped at ``iteration`` by non-finite numbers with ``setting`` in force: exit status 1 and one line
    on stderr saying where, a summary.json that records the divergence as a finished run (no evaluation: the
    weights are not finite), and the last good checkpoint, of the iteration before, left as it was with finite
    weights (``checkpoint_key``: where they are in it, "a/b" for checkpoint["a"]["b"]). The summary."""
    assert result.returncode == 1, result.stderr
    [line] = result.stderr.strip().splitlines()
    assert "non-finite " in line and f" at iteration {iteration} " in line and setting in line, line
    assert "summary.json records the divergence" in line and "the last good checkpoint is" in line, line
    recorded = summary(run_dir)
    diverged = recorded["diverged"]
    assert diverged == {"what": diverged["what"], "iteration": iteration, "global_step": recorded["global_step"]}
    assert diverged["what"] in ("loss", "action") and recorded["iterations"] == iteration
    assert recorded["eval"] | {"level_seeds": []} == {"episodes": 0, "mean_return": None, "std_return": None,
                                                      "returns": [], "level_seeds": []}  # Procgen's has its levels
    assert recorded["bandit"] is not None and recorded["settings_in_force"]
    assert not os.path.exists(os.path.join(run_dir, "summary.json.tmp"))
    checkpoint = torch.load(os.path.join(run_dir, "checkpoint.pt"), weights_only=False)
    assert checkpoint["iteration"] == iteration - 1 and checkpoint["global_step"] < recorded["global_step"]
    weights = checkpoint
    for key in checkpoint_key.split("/"):
        weights = weights[key]
    assert all(torch.isfinite(p).all() for p in weights.values())
    # The final score is the training score it had reached: the checkpoint's last episodes and the diverging
    # iteration's, at most 100.
    assert recorded["final_score_episodes"] >= min(len(checkpoint["recent_returns"]), 100)
    assert (recorded["final_score"] is None) == (recorded["final_score_episodes"] == 0)
    if recorded["final_score_episodes"] == len(checkpoint["recent_returns"]):
        assert recorded["final_score"] == (float(np.mean(checkpoint["recent_returns"]))
                                           if checkpoint["recent_returns"] else None)
    return recorded


def summary(run_dir: str) -> dict:
    with open(os.path.join(run_dir, "summary.json")) as f:
        return json.load(f)


def scalars(run_dir: str) -> dict[str, list[tuple[int, float]]]:
    """Every scalar series in the run's TensorBoard event files, read with tensorboard's own reader."""
    accumulator = EventAccumulator(run_dir, size_guidance={"scalars": 0})
    accumulator.Reload()
    return {tag: [(e.step, e.value) for e in accumulator.Scalars(tag)] for tag in accumulator.Tags()["scalars"]}


def files_under(path: str) -> list[str]:
    return [os.path.join(d, f) for d, _, files in os.walk(path) for f in files] if os.path.exists(path) else []


def run_bad_inputs(script: str, arg_lists: list[list[str]], base) -> list[tuple[str, subprocess.CompletedProcess]]:
    """Every bad input at once, each with its own empty runs directory: [(runs directory, result)]."""
    runs = [os.path.join(str(base), str(k)) for k in range(len(arg_lists))]
    return list(zip(runs, run_concurrently(script, [["--runs-dir", r, *args] for r, args in zip(runs, arg_lists)])))


def assert_refused(script: str, runs_dir: str, result: subprocess.CompletedProcess, named: str) -> None:
    """The bad-input convention: exit status 2, one line `<script>: error: ...` naming the bad value (no import
    notices or warnings around it), nothing on stdout, nothing written."""
    assert result.returncode == 2, result.stderr
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and named in lines[0], result.stderr
    assert lines[0].startswith(f"{script.removesuffix('.py')}: error: "), lines[0]
    assert result.stdout == ""
    assert files_under(runs_dir) == []


def assert_existing_run_and_foreign_checkpoint_refused(script: str, tmp_path) -> None:
    """An existing run directory is never reused, and a checkpoint that is not the script's is refused by name."""
    (tmp_path / "taken").mkdir()
    result = run(script, "--runs-dir", str(tmp_path), "--run-name", "taken")
    assert result.returncode == 2 and "already exists" in result.stderr
    (tmp_path / "junk").mkdir()
    (tmp_path / "junk" / "checkpoint.pt").write_bytes(b"not a checkpoint")
    result = run(script, "--resume", str(tmp_path / "junk"))
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert "unreadable" in result.stderr
    assert sorted(os.listdir(tmp_path)) == ["junk", "taken"] and os.listdir(tmp_path / "taken") == []


def real_rollout(script, agent, envs, obs: np.ndarray, args) -> dict[str, torch.Tensor]:
    """--num-steps steps of the agent's policy (float32) on real environments, stored as the training loop stores
    them, with GAE returns and advantages (normalized, as the update uses them): one update's inputs, all of
    them one minibatch. Rewards are sign-clipped, on the scale of the scripts' normalized rewards."""
    stored: dict[str, list] = {"obs": [], "actions": [], "logprobs": [], "values": []}
    rewards, dones = np.zeros((args.num_steps, args.num_envs)), np.zeros((args.num_steps, args.num_envs))
    done = np.zeros(args.num_envs, dtype=bool)
    for step in range(args.num_steps):
        obs_t = torch.from_numpy(obs)
        with torch.no_grad():
            log_probs, value = agent(obs_t)
        action = script.sample(log_probs)
        for key, x in zip(stored, (obs_t, action, log_probs.gather(1, action.unsqueeze(1)).squeeze(1), value)):
            stored[key].append(x)
        dones[step] = done
        obs, reward, terminated, truncated, _ = envs.step(action.numpy())
        done = terminated | truncated
        rewards[step] = np.sign(reward)
    with torch.no_grad():
        next_value = agent.get_value(torch.from_numpy(obs)).numpy()
    values = torch.stack(stored["values"]).numpy()
    advantages, last = np.zeros_like(rewards), 0.0
    for t in reversed(range(args.num_steps)):
        nonterminal, next_values = ((1 - done, next_value) if t == args.num_steps - 1
                                    else (1 - dones[t + 1], values[t + 1]))
        delta = rewards[t] + args.gamma * next_values * nonterminal - values[t]
        advantages[t] = last = delta + args.gamma * args.gae_lambda * nonterminal * last
    batch = {key: torch.cat(x) for key, x in stored.items()}
    batch["returns"] = torch.from_numpy(advantages + values).float().reshape(-1)
    advantages = torch.from_numpy(advantages).float().reshape(-1)
    batch["advantages"] = (advantages - advantages.mean()) / (advantages.std() + 1e-8)
    return batch


def bf16_against_float32(script, agent, args, batch: dict[str, torch.Tensor]) -> dict[str, float]:
    """The PPO loss's gradient on `batch` (the script's own ppo_loss) and the probability ratio, under bf16 and
    under float32 with the same weights: the gradients' cosine similarity and relative norm difference, and the
    largest |ratio_bf16 - ratio_float32| over the batch."""
    gradients, ratios = {}, {}
    settings = script.Settings.from_args(args)  # the settings in force: the command line's
    for precision in ("float32", "bf16"):
        agent.precision = precision
        agent.zero_grad(set_to_none=True)
        loss, _ = script.ppo_loss(agent, args, settings, batch["obs"], batch["actions"], batch["logprobs"],
                                  batch["advantages"], batch["returns"], batch["values"])
        loss.backward()
        assert all(p.grad.dtype == torch.float32 for p in agent.parameters())
        gradients[precision] = torch.cat([p.grad.flatten() for p in agent.parameters()])
        with torch.no_grad():
            log_probs, _ = agent(batch["obs"])
        ratios[precision] = (log_probs.gather(1, batch["actions"].unsqueeze(1)).squeeze(1) - batch["logprobs"]).exp()
    g32, g16 = gradients["float32"], gradients["bf16"]
    return {"cosine": torch.nn.functional.cosine_similarity(g32, g16, dim=0).item(),
            "relative_norm_difference": ((g16 - g32).norm() / g32.norm()).item(),
            "ratio_deviation": (ratios["bf16"] - ratios["float32"]).abs().max().item()}


def assert_bf16_resume_equals_uninterrupted(script: str, tmp_path, args: list[str], score_key: str) -> None:
    """A bf16 run killed after its first checkpoint and resumed without --precision equals the same bf16 run
    uninterrupted; its checkpoint holds float32 weights and Adam moments; a float32 run started from that
    checkpoint (--init-from takes only state) logs other losses, so a resume that fell back to float32 could not
    have matched. `args` is a plain-PPO command line with --checkpoint-every 2 and a --runs-dir."""
    with ThreadPoolExecutor(1) as pool:
        whole = pool.submit(run, script, *args, "--precision", "bf16", "--run-name", "whole")
        kill_after_first_checkpoint(script, str(tmp_path / "killed"), *args, "--precision", "bf16",
                                    "--run-name", "killed")
        assert whole.result().returncode == 0, whole.result().stderr
    checkpoint = torch.load(tmp_path / "killed" / "checkpoint.pt", weights_only=False)
    assert checkpoint["iteration"] < 4 and checkpoint["config"]["precision"] == "bf16"
    # The weights and Adam's moments stay float32 (autocast casts per operation).
    assert all(t.dtype == torch.float32 for t in checkpoint["agent"].values())
    assert all(t.dtype == torch.float32 for state in checkpoint["optimizer"]["state"].values()
               for name, t in state.items() if name != "step")
    shutil.copytree(tmp_path / "killed", tmp_path / "at_kill")  # the resumed run replaces its checkpoint
    for result in run_concurrently(script, [["--resume", str(tmp_path / "killed"), "--quiet"],
                                            [*args, "--init-from", str(tmp_path / "at_kill"),
                                             "--run-name", "float32"]]):
        assert result.returncode == 0, result.stderr

    whole, resumed = summary(str(tmp_path / "whole")), summary(str(tmp_path / "killed"))
    assert whole["precision"] == resumed["precision"] == "bf16"
    for key in ("global_step", score_key, "eval"):
        assert whole[key] == resumed[key], key
    a, b = scalars(str(tmp_path / "whole")), scalars(str(tmp_path / "killed"))
    for tag in ("losses/value_loss", "losses/policy_loss", "losses/entropy", "losses/approx_kl",
                "charts/episodic_return"):
        assert a[tag] == b[tag], tag
    float32 = scalars(str(tmp_path / "float32"))
    assert summary(str(tmp_path / "float32"))["precision"] == "float32"
    after_kill = [(step, loss) for step, loss in a["losses/value_loss"] if step > checkpoint["global_step"]]
    assert [step for step, _ in float32["losses/value_loss"]] == [step for step, _ in after_kill]
    assert float32["losses/value_loss"] != after_kill


# Three clusters of one value each, every value the scripts' default: whatever the bandit chooses, every update is
# the fixed-settings update, so runs that differ only in their credit train identically.
NEUTRAL_SPACE = {"vf_coef": [0.5], "clip_coef": [0.2], "max_grad_norm": [0.5]}


def assert_authors_credit_timing_and_exact_resume(script: str, tmp_path, args: list[str]) -> None:
    """--ultho-utility authors-return: the run's first choice is withdrawn uncredited; at every later iteration the
    choice just made is credited, before its update, with the mean GAE return of the rollout just collected. That
    number is the one --ultho-utility return measures at the same iteration and gives to the *previous* choice, so
    a `return` run over NEUTRAL_SPACE (identical training) supplies it; the authors' choices must then be those of
    a bandit fed exactly that timing. Killed after its first checkpoint and resumed, the run equals the
    uninterrupted one. `args`: a tiny run of about six iterations with --checkpoint-every 2 and a --runs-dir."""
    clusters = ["--ultho-clusters", *(f"{name}={values[0]}" for name, values in NEUTRAL_SPACE.items()),
                "--ultho-c", "0.5", "--ultho-window", "2", "--eval-episodes", "0", "--quiet"]
    authors = [*args, *clusters, "--ultho-utility", "authors-return"]
    for result in run_concurrently(script, [[*authors, "--run-name", "whole"],
                                            [*args, *clusters, "--ultho-utility", "return", "--run-name", "return"]]):
        assert result.returncode == 0, result.stderr
    kill_after_first_checkpoint(script, str(tmp_path / "killed"), *authors, "--run-name", "killed")
    assert not (tmp_path / "killed" / "summary.json").exists()
    run_ok(script, "--resume", str(tmp_path / "killed"), "--quiet")

    whole, other = scalars(str(tmp_path / "whole")), scalars(str(tmp_path / "return"))
    chosen = [int(v) for _, v in whole["ultho/selected_cluster"]]
    measured = [v for _, v in other["ultho/credit"]]  # the mean GAE return of rollouts 2, 3, ...
    assert len(measured) == len(chosen) - 1 >= 4
    assert whole["ultho/credit"] == other["ultho/credit"]  # the same numbers at the same iterations ...
    assert whole["losses/value_loss"] == other["losses/value_loss"]  # ... of the same training
    assert chosen[:2] == [0, 0]  # 1: every bound 0; withdrawn, so 2 is selection number 1 again
    replay = ULTHO(NEUTRAL_SPACE, c=0.5, window=2)
    expected = [replay.select()]
    replay.withdraw()
    for credit in measured:  # ... but each credits the choice made at its own iteration
        expected.append(replay.select())
        replay.update(credit)
    assert [replay.cluster_names.index(name) for name, _ in expected] == chosen
    assert summary(str(tmp_path / "whole"))["bandit"]["selections"] == replay.selections()
    assert summary(str(tmp_path / "whole"))["bandit"]["utility"] == "authors-return"

    resumed = scalars(str(tmp_path / "killed"))
    assert summary(str(tmp_path / "whole"))["bandit"] == summary(str(tmp_path / "killed"))["bandit"]
    for tag in ("ultho/selected_cluster", "ultho/credit", "ultho/ucb/vf_coef", "losses/value_loss"):
        assert whole[tag] == resumed[tag], tag


def assert_round_robin_rotation_in_force_and_exact_resume(script: str, tmp_path, args: list[str]) -> None:
    """--ultho-strategy round-robin over two clusters: the clusters alternate and each takes its values in turn,
    whatever the credits (two seeds, different training, the same rotation); a value stays in force until its
    cluster comes round again (hparams/ tags); no bandit statistic is logged; killed after its first checkpoint
    and resumed, the run equals the uninterrupted one. `args`: a tiny run of six iterations with
    --checkpoint-every 2 and a --runs-dir."""
    rotation = [*args, "--ultho-strategy", "round-robin", "--ultho-clusters", "update_epochs=2,1",
                "vf_coef=0.25,1.0", "--eval-episodes", "0", "--quiet"]
    for result in run_concurrently(script, [[*rotation, "--seed", "1", "--run-name", "whole"],
                                            [*rotation, "--seed", "2", "--run-name", "other-seed"]]):
        assert result.returncode == 0, result.stderr
    kill_after_first_checkpoint(script, str(tmp_path / "killed"), *rotation, "--seed", "1", "--run-name", "killed")
    assert not (tmp_path / "killed" / "summary.json").exists()
    run_ok(script, "--resume", str(tmp_path / "killed"), "--quiet")

    whole, other, resumed = (scalars(str(tmp_path / name)) for name in ("whole", "other-seed", "killed"))

    def values(series, tag):
        return [v for _, v in series[tag]]

    assert values(whole, "ultho/selected_cluster") == [0.0, 1.0, 0.0, 1.0, 0.0, 1.0]
    assert values(whole, "hparams/update_epochs") == [2.0, 2.0, 1.0, 1.0, 2.0, 2.0]
    assert values(whole, "hparams/vf_coef") == pytest.approx([0.5, 0.25, 0.25, 1.0, 1.0, 0.25])  # 0.5: default
    assert values(whole, "ultho/credit") != values(other, "ultho/credit")
    for tag in ("ultho/selected_cluster", "hparams/update_epochs", "hparams/vf_coef"):
        assert values(other, tag) == values(whole, tag), tag
    assert not [tag for tag in whole if tag.startswith(("ultho/ucb", "ultho/bonus"))]
    # The sixth choice is credited after the run's last rollout, which never comes.
    assert summary(str(tmp_path / "whole"))["bandit"]["selections"] == {"update_epochs": 3, "vf_coef": 2}
    for tag in ("ultho/selected_cluster", "hparams/vf_coef", "ultho/credit", "losses/value_loss"):
        assert whole[tag] == resumed[tag], tag


def wandb_offline_runs(wandb_dir) -> dict[str, list]:
    """{run id: its records} of every offline W&B run under ``wandb_dir`` (WANDB_DIR), read back from the
    run-<id>.wandb files that `wandb sync` would upload: W&B's protobuf Records in a LevelDB-style log (a 7-byte
    header, then 32 KiB blocks of chunks, each a 4-byte checksum, a 2-byte length and a 1-byte type: full, first,
    middle, last). A resumed run's second file adds to the same id."""
    from wandb.proto import wandb_internal_pb2

    runs: dict[str, list] = {}
    for directory, _, names in sorted(os.walk(str(wandb_dir))):
        for name in sorted(names):
            if not (name.startswith("run-") and name.endswith(".wandb")):
                continue
            with open(os.path.join(directory, name), "rb") as f:
                data = f.read()
            assert data[:4] == b":W&B", name
            position, pending, records = 7, b"", []
            while position + 7 <= len(data):
                left_in_block = 32768 - position % 32768
                kind = data[position + 6]
                if left_in_block < 7 or kind == 0:  # the block's zero padding
                    position += left_in_block
                    continue
                length = int.from_bytes(data[position + 4:position + 6], "little")
                pending += data[position + 7:position + 7 + length]
                position += 7 + length
                if kind in (1, 4):  # a full record, or the last chunk of one
                    record = wandb_internal_pb2.Record()
                    record.ParseFromString(pending)
                    records.append(record)
                    pending = b""
            runs.setdefault(name.removeprefix("run-").removesuffix(".wandb"), []).extend(records)
    return runs


def wandb_history(records: list) -> dict[str, list[tuple[int, float]]]:
    """{tag: [(global step, value)]} of the scalars W&B received (synced from TensorBoard: keyed by global_step)."""
    series: dict[str, list[tuple[int, float]]] = {}
    for record in records:
        if record.WhichOneof("record_type") != "history":
            continue
        row = {item.key or "/".join(item.nested_key): json.loads(item.value_json) for item in record.history.item}
        for tag, value in row.items():
            if not tag.startswith("_") and tag != "global_step" and isinstance(value, (int, float)):
                series.setdefault(tag, []).append((int(row.get("global_step", -1)), float(value)))
    return series


def without_wandb_login(home) -> dict:
    """An environment in which W&B finds no key: no WANDB_API_KEY, no netrc (HOME is empty), not offline."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("WANDB_") and k != "NETRC"}
    return {**env, "HOME": str(home)}

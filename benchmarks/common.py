"""Shared helpers for the throughput benchmarks: run a training script for real and compare ULTHO on/off, or
float32 with bf16 (--precision).

Every figure comes from the script's own summary.json (steps / wall time of training, evaluation excluded).
The configurations alternate, so drifting machine load hits both sides alike; medians are reported.
"""

import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def machine() -> str:
    return f"{platform.machine()}, {os.cpu_count()} cores, Python {platform.python_version()}"


def run_script(script: str, args: list[str]) -> dict:
    """Runs `python <script> <args>` in a scratch runs directory and returns its summary.json."""
    with tempfile.TemporaryDirectory() as runs_dir:
        cmd = [sys.executable, os.path.join(REPO, script), *args, "--runs-dir", runs_dir, "--run-name", "bench",
               "--eval-episodes", "0", "--quiet"]
        subprocess.run(cmd, check=True, cwd=REPO)
        with open(os.path.join(runs_dir, "bench", "summary.json")) as f:
            return json.load(f)


def ultho_on_off(script: str, args: list[str], neutral_clusters: list[str], repeats: int
                 ) -> tuple[dict[str, list[float]], list[float]]:
    """SPS of `repeats` alternating runs: PPO (--no-ultho), ULTHO over a neutral search space and ULTHO over
    the paper's; and ULTHO's share of each ULTHO run's wall time, which the script measures itself.

    The neutral space gives every cluster the PPO default as its only value, so the training is identical to
    PPO's (same seed, same settings) while the bandit selects, credits and logs all the same: the difference
    to PPO is ULTHO's own cost. With the paper's space the choices change the work (a minibatch size of 512
    halves the optimizer steps of 256), so that row shows SPS, not overhead. On a shared machine whose speed
    drifts, the in-run share (summary.json's ultho_share) resolves small costs that SPS differences cannot.
    """
    sps: dict[str, list[float]] = {"PPO (--no-ultho)": [], "ULTHO, neutral space": [], "ULTHO, paper space": []}
    shares: list[float] = []
    for _ in range(repeats):
        sps["PPO (--no-ultho)"].append(run_script(script, [*args, "--no-ultho"])["sps"])
        for row, extra in (("ULTHO, neutral space", ["--ultho-clusters", *neutral_clusters]),
                           ("ULTHO, paper space", ["--ultho"])):
            summary = run_script(script, [*args, *extra])
            sps[row].append(summary["sps"])
            shares.append(summary["ultho_share"])
    return sps, shares


def print_table(title: str, rows: dict[str, list[float]], shares: list[float],
                reference: str = "PPO (--no-ultho)") -> None:
    """A markdown table: median, min and max SPS per row, each median as a ratio of the reference's, then
    ULTHO's cost both ways."""
    ref = statistics.median(rows[reference])
    print(f"# {title}  ({machine()})")
    print("| what | median steps/s | min | max | ratio to PPO |")
    print("|---|---|---|---|---|")
    for name, values in rows.items():
        med = statistics.median(values)
        print(f"| {name} | {med:,.0f} | {min(values):,.0f} | {max(values):,.0f} | {med / ref:.3f} |")
    neutral = statistics.median(rows["ULTHO, neutral space"])
    print(f"\nULTHO's cost, SPS of the neutral space vs PPO (identical training): {100 * (1 - neutral / ref):+.1f}% "
          f"(medians of {len(rows[reference])} alternating runs; as noisy as the min-max spread above)")
    print(f"ULTHO's cost, measured inside each ULTHO run (select, credit, apply, bandit logging as a share of "
          f"wall time): median {100 * statistics.median(shares):.3f}%, max {100 * max(shares):.3f}%")


def precision_side_by_side(script: str, args: list[str], repeats: int) -> dict[str, list[dict]]:
    """summary.json of `repeats` alternating runs in float32 and in bf16 (--precision), the same otherwise."""
    runs: dict[str, list[dict]] = {"float32": [], "bf16": []}
    for _ in range(repeats):
        for precision, summaries in runs.items():
            summaries.append(run_script(script, [*args, "--precision", precision]))
    return runs


def print_precision_table(title: str, runs: dict[str, list[dict]]) -> None:
    """A markdown table: per precision the median, min and max SPS, the median as a ratio of float32's, peak
    memory (resident, and CUDA's allocator when training on a GPU), and the median shares of the training wall
    time spent in the rollout (acting and stepping the environments) and in the PPO update; then bf16's times
    relative to float32's, phase by phase."""
    def median(summaries: list[dict], key: str) -> float:
        return statistics.median(s[key] for s in summaries)

    def peak(summaries: list[dict], key: str) -> str:
        values = [s[key] for s in summaries if s[key] is not None]
        return f"{max(values):,.0f}" if values else "-"

    ref = median(runs["float32"], "sps")
    print(f"# {title}, training on {runs['float32'][0]['device']}  ({machine()})")
    print("| precision | median steps/s | min | max | ratio to float32 | peak RSS (MB, max) | peak CUDA (MB, max) "
          "| rollout share | update share |")
    print("|---|---|---|---|---|---|---|---|---|")
    for precision, summaries in runs.items():
        sps = [s["sps"] for s in summaries]
        shares = {phase: statistics.median(s[f"{phase}_seconds"] / s["wall_time_s"] for s in summaries)
                  for phase in ("rollout", "update")}
        print(f"| {precision} | {statistics.median(sps):,.0f} | {min(sps):,.0f} | {max(sps):,.0f} | "
              f"{statistics.median(sps) / ref:.3f} | {peak(summaries, 'peak_rss_mb')} | "
              f"{peak(summaries, 'peak_cuda_mb')} | {shares['rollout']:.1%} | {shares['update']:.1%} |")
    ratios = [f"{label} {median(runs['bf16'], key) / median(runs['float32'], key):.3f}" for label, key in
              (("update", "update_seconds"), ("rollout", "rollout_seconds"), ("training wall time", "wall_time_s"))]
    print(f"\nbf16's time / float32's (medians of {len(runs['float32'])} alternating runs): {', '.join(ratios)}")

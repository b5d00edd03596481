"""Soak: memory of one long `tpo train` run, sampled over time.

    python benchmarks/soak.py --steps 10000000 --csv soak.csv
    python benchmarks/soak.py --steps 1000000 -- --env mo-gymnasium:deep-sea-treasure-v0 \\
        --objectives treasure,time --dag "treasure>time"

Runs ``tpo train`` (run directory, metrics, TensorBoard, checkpoints: the whole user
path) in a subprocess into a temporary directory and samples its resident set size
(``VmRSS`` of ``/proc/PID/status``, Linux) every ``--interval`` seconds, with the env
steps done so far (from the run's ``metrics.csv``). Prints RSS at every tenth of the
run, the peaks of training and of the final saving and evaluation, and the growth
during training after warm-up (from 20 % of the steps on), in MB per million steps.
Arguments after ``--`` replace the default ``--map home --dag M>A>G``.
"""

from __future__ import annotations

import argparse
import csv
import subprocess
import sys
import tempfile
import time
from pathlib import Path


def rss_mb(pid: int) -> float | None:
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def steps_done(run_dir: Path) -> int:
    """The env steps of the last row of ``metrics.csv`` (0 before the first)."""
    try:
        with open(run_dir / "metrics.csv") as f:
            rows = f.read().splitlines()
    except OSError:
        return 0
    if len(rows) < 2:
        return 0
    header = rows[0].split(",")
    whole = [r.split(",") for r in rows[1:] if r.count(",") == len(header) - 1]
    try:  # the last whole row (a row being written may be cut short)
        return int(float(whole[-1][header.index("timesteps")]))
    except (ValueError, IndexError):
        return 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=10_000_000)
    parser.add_argument("--interval", type=float, default=1.0, help="seconds between samples")
    parser.add_argument("--csv", help="write the samples (seconds, steps, rss_mb) here")
    parser.add_argument("train_args", nargs="*", help="arguments for tpo train (after --)")
    args = parser.parse_args()
    train_args = args.train_args or ["--map", "home", "--dag", "M>A>G"]

    with tempfile.TemporaryDirectory() as tmp:
        run_dir = Path(tmp) / "soak"
        cmd = [sys.executable, "-c", "import sys; from tpo.cli.main import main; "
               "sys.exit(main())", "train", *train_args, "--steps", str(args.steps),
               "--out", str(run_dir), "--quiet", "--episodes", "10"]
        t0 = time.perf_counter()
        proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL)
        samples: list[tuple[float, int, float]] = []
        while proc.poll() is None:
            rss = rss_mb(proc.pid)
            if rss is not None:
                samples.append((time.perf_counter() - t0, steps_done(run_dir), rss))
            time.sleep(args.interval)
        if proc.returncode:
            sys.exit(f"tpo train failed with exit code {proc.returncode}")
    wall = time.perf_counter() - t0

    if args.csv:
        with open(args.csv, "w", newline="") as f:
            writer = csv.writer(f)
            writer.writerow(["seconds", "steps", "rss_mb"])
            writer.writerows((f"{t:.1f}", n, f"{r:.1f}") for t, n, r in samples)
    print(f"{args.steps} steps in {wall:.0f} s ({args.steps / wall / 1e3:.1f} k steps/s "
          f"including compilation and evaluation), {len(samples)} samples")
    for tenth in range(1, 11):
        at = [r for _, n, r in samples if n <= args.steps * tenth / 10]
        if at:
            print(f"  {tenth * 10:3d} % of steps: RSS {at[-1]:7.1f} MB")
    if not samples:
        sys.exit("no samples: the run ended before the first one")
    last = max(n for _, n, _ in samples)
    training = [(n, r) for _, n, r in samples if n < last]  # then saving and evaluation
    warm = [(n, r) for n, r in training if n >= args.steps * 0.2]
    during = f"{max(r for _, r in training):.1f} MB" if training else "not sampled"
    print(f"peak RSS {max(r for _, _, r in samples):.1f} MB; during training {during}; "
          f"saving and evaluation {max(r for _, n, r in samples if n == last):.1f} MB")
    if len(warm) >= 2:
        (n0, r0), (n1, r1) = warm[0], warm[-1]
        print(f"training after warm-up: {r0:.1f} MB at {n0} steps -> {r1:.1f} MB at {n1} "
              f"steps ({(r1 - r0) / (n1 - n0) * 1e6:+.2f} MB per million steps)")


if __name__ == "__main__":
    main()

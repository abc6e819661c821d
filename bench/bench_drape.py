"""End-to-end drape timings through the public API, optionally side by side with an earlier commit.

    .venv/bin/python bench/bench_drape.py [--repeats 7] [--rounds 2] [--base COMMIT] [--cold]
        [--devices cpu cuda] [--out results/bench_drape]

Rows (the bundled model, T = 15, one torch thread, medians):
- warm drape, same pose: `Draper.drape("default")` again in the same process (the default
  T-shirt on the default body and pose; skinning transfer fitted, body posed before);
- X_init: the drape's `init_s` phase of that call (skinning transfer, strain limiting, packing);
- warm drape, new pose: the same T-shirt on a pose the Draper has not posed yet (each pose drawn
  by the seeded sampler beforehand and passed as an array, so the sampler is not timed);
- batch of 8: one `drape` call of the T-shirt on 8 poses (the same 8 every call), per garment;
- with `--cold`: a new process running `physdrape drape --out TMP` (imports, model and body
  load, transfer fit, drape, every output file).

With `--base COMMIT` the same measurements run on that commit's source (a temporary git worktree
with the same virtual environment), in separate processes that alternate with this commit's over
`--rounds` rounds, so that both see the same machine load; the table gives both medians and their
ratio. On a shared machine the numbers move with the load: the file records the load average.
Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
ROWS = {
    "same_pose": "warm drape, same pose [ms]",
    "x_init": "X_init (init phase of the same-pose drape) [ms]",
    "new_pose": "warm drape, new pose [ms]",
    "batch8": "batch of 8 poses, per garment [ms]",
}
#: The issue's targets [ms] (one thread, medians).
TARGETS = {"same_pose": 150.0, "x_init": 20.0, "new_pose": 250.0, "batch8": 100.0}


def worker(repeats: int, device: str, threads: int) -> dict[str, list[float]]:
    """Time the rows in this process (the source on sys.path) and return the samples [ms]."""
    import torch

    torch.set_num_threads(threads)
    from physdrape.api import Draper

    draper = Draper(device=device) if device != "cpu" else Draper()
    draper.drape("default")  # fits and caches the skinning transfer, poses the default body
    out: dict[str, list[float]] = {key: [] for key in ROWS}
    for _ in range(repeats):
        t = time.perf_counter()
        [res] = draper.drape("default")
        out["same_pose"].append(1e3 * (time.perf_counter() - t))
        out["x_init"].append(1e3 * res.timings["init_s"])
    poses = [draper.poses(f"random:{1000 + k}")[0].pose[0] for k in range(repeats + 1)]
    draper.drape("default", pose=poses[0])  # a first new pose outside the timing
    for pose in poses[1:]:
        t = time.perf_counter()
        draper.drape("default", pose=pose)
        out["new_pose"].append(1e3 * (time.perf_counter() - t))
    eight = [draper.poses(f"random:{k}")[0].pose[0] for k in range(8)]
    draper.drape("default", pose=eight, batch_size=8)
    for _ in range(max(2, repeats // 2)):
        t = time.perf_counter()
        draper.drape("default", pose=eight, batch_size=8)
        out["batch8"].append(1e3 * (time.perf_counter() - t) / 8)
    return out


def _run_worker(src: Path, repeats: int, device: str, threads: int) -> dict[str, list[float]]:
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS=str(threads))
    proc = subprocess.run([sys.executable, __file__, "--worker", "--repeats", str(repeats), "--device", device,
                           "--threads", str(threads)], env=env, capture_output=True, text=True, cwd=ROOT, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"the timing process for {src} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _cold_cli(src: Path, repeats: int, threads: int) -> list[float]:
    env = dict(os.environ, PYTHONPATH=str(src), OMP_NUM_THREADS=str(threads))
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeats):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", "physdrape.cli", "drape", "--out", f"{tmp}/o{k}", "--threads",
                            str(threads)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                           env=env, cwd=ROOT)
            times.append(1e3 * (time.perf_counter() - t))
    return times


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True, text=True).stdout.strip()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per row and process")
    parser.add_argument("--rounds", type=int, default=2, help="processes per source, alternating")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--base", default=None, help="an earlier commit to time side by side")
    parser.add_argument("--devices", nargs="+", default=["cpu"], help="cpu and/or cuda (this commit only)")
    parser.add_argument("--cold", action="store_true", help="also time a cold `physdrape drape` (new process)")
    parser.add_argument("--out", default="results/bench_drape")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--device", default="cpu", help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.repeats, args.device, args.threads)))
        return

    import torch
    from report import source_lines, write_report

    from physdrape.provenance import provenance

    devices = [d for d in args.devices if d == "cpu" or torch.cuda.is_available()]
    skipped = [d for d in args.devices if d not in devices]
    sources = {"this commit": ROOT / "src"}
    base_dir = None
    if args.base:
        base_dir = Path(tempfile.mkdtemp(prefix="physdrape-base-"))
        _git("worktree", "add", "--detach", str(base_dir / "tree"), args.base)
        sources[f"base {args.base[:10]}"] = base_dir / "tree" / "src"
    samples: dict[str, dict[str, list[float]]] = {}
    load = []
    try:
        for _ in range(args.rounds):
            for device in devices:
                for name, src in sources.items():
                    if device != "cpu" and name != "this commit":
                        continue
                    key = f"{name} ({device})"
                    got = _run_worker(src, args.repeats, device, args.threads)
                    load.append(os.getloadavg()[0])
                    for row, values in got.items():
                        samples.setdefault(key, {}).setdefault(row, []).extend(values)
            if args.cold:
                for name, src in sources.items():
                    samples.setdefault(f"{name} (cpu)", {}).setdefault("cold_cli", []).extend(
                        _cold_cli(src, 1, args.threads))
    finally:
        if base_dir is not None:
            _git("worktree", "remove", "--force", str(base_dir / "tree"))
    rows = dict(ROWS, **({"cold_cli": "cold `physdrape drape` (new process, all outputs) [ms]"} if args.cold else {}))
    medians = {key: {row: statistics.median(v) for row, v in got.items()} for key, got in samples.items()}
    columns = list(medians)
    command = shlex.join(["python", *sys.argv])
    record = {"command": command, "provenance": provenance(), "threads": args.threads, "repeats": args.repeats,
              "rounds": args.rounds, "load_average_during": load, "load_average_end": os.getloadavg(),
              "devices_skipped": skipped, "targets_ms": TARGETS, "samples_ms": samples, "medians_ms": medians}
    head = ["| row | " + " | ".join(columns) + (" | ratio base / this |" if args.base else " |") + " target |",
            "|---|" + "---:|" * len(columns) + ("---:|" if args.base else "") + "---:|"]
    lines = ["# Drape timings through the public API (bundled model, T = 15)", "",
             *source_lines(command, record["provenance"]),
             f"{args.threads} torch thread(s); medians over {args.rounds} alternating process(es) per source × "
             f"{args.repeats} calls; load average (1 min) during the run "
             + ", ".join(f"{v:.2f}" for v in load) + (f"; not available here: {', '.join(skipped)}" if skipped else ""),
             "", *head]
    for row, label in rows.items():
        values = [medians[c].get(row) for c in columns]
        cells = " | ".join("–" if v is None else f"{v:.0f}" for v in values)
        ratio = ""
        if args.base:
            this, base = medians[columns[0]].get(row), medians.get(f"base {args.base[:10]} (cpu)", {}).get(row)
            ratio = f" {base / this:.2f} |" if this and base else " – |"
        target = f"≤ {TARGETS[row]:.0f}" if row in TARGETS else "–"
        lines.append(f"| {label} | {cells} |{ratio} {target} |")
    write_report(args.out, lines, record)


if __name__ == "__main__":
    main()

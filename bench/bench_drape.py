"""End-to-end timing of `physdrape drape` on the default inputs (bundled T-shirt, default body,
relaxed pose, cotton, 15 solver steps).

    .venv/bin/python bench/bench_drape.py [--checkpoint DIR] [--threads 1] [--repeats 3]

Rows:
- cold CLI: a new process running `physdrape drape --out TMP` (imports, model + body load,
  skinning-transfer fit, drape, OBJ/PLY/GLB + PNG + report.json), wall time;
- cold API: a new process: import, `Draper(...)`, one `drape("default")` (no files written);
- warm drape: `Draper.drape("default")` again in the same process (transfer cached), median;
- warm drape + outputs: the same plus `save` (OBJ, PLY, GLB) and `render` (PNG);
- batch of 8: one `drape` call on 8 garments (the default T-shirt on 8 sampled poses), garments/s.
On a shared machine the numbers move with the load: the table prints the 1-minute load average.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CLI = [sys.executable, "-m", "physdrape.cli"]


def _cold(cmd: list[str], env: dict) -> float:
    t = time.perf_counter()
    subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=ROOT)
    return time.perf_counter() - t


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--checkpoint", default=None, help="default: the bundled model, else runs/cpu_default")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()

    import torch

    from physdrape.api import Draper
    from physdrape.checkpoint import bundled_model

    checkpoint = args.checkpoint
    if checkpoint is None:
        checkpoint = str(bundled_model()) if bundled_model().exists() else str(ROOT / "runs" / "cpu_default")
    env = dict(os.environ, OMP_NUM_THREADS=str(args.threads))
    rows: list[tuple[str, float, str]] = []
    with tempfile.TemporaryDirectory() as tmp:
        cold_cli = [_cold([*CLI, "drape", "--checkpoint", checkpoint, "--out", f"{tmp}/o{k}", "--threads",
                           str(args.threads)], env) for k in range(args.repeats)]
        rows.append(("cold CLI `physdrape drape` (new process, all outputs)", statistics.median(cold_cli), "s"))
        code = (f"import torch; torch.set_num_threads({args.threads}); from physdrape.api import Draper; "
                f"Draper({checkpoint!r}).drape('default')")
        cold_api = [_cold([sys.executable, "-c", code], env) for _ in range(args.repeats)]
        rows.append(("cold API (new process: import, load, 1 drape)", statistics.median(cold_api), "s"))

        torch.set_num_threads(args.threads)
        draper = Draper(checkpoint)
        draper.drape("default")  # fits and caches the skinning transfer
        warm, warm_out = [], []
        for k in range(args.repeats):
            t = time.perf_counter()
            [res] = draper.drape("default")
            warm.append(time.perf_counter() - t)
            t = time.perf_counter()
            [res] = draper.drape("default")
            res.save(f"{tmp}/w{k}")
            res.render(f"{tmp}/w{k}/render.png")
            warm_out.append(time.perf_counter() - t)
        rows.append(("warm drape (Draper reused, no files)", statistics.median(warm), "s"))
        rows.append(("warm drape + OBJ/PLY/GLB + PNG", statistics.median(warm_out), "s"))
        phases = {k: v for k, v in res.timings.items() if k.endswith("_s") and k != "per_garment_s"}

        poses = [f"random:{k}" for k in range(8)]
        draper.drape("default", pose=poses)  # warm the pose sampler
        times = []
        for _ in range(args.repeats):
            t = time.perf_counter()
            draper.drape("default", pose=poses, batch_size=8)
            times.append(time.perf_counter() - t)
        rows.append(("batch of 8 (default T-shirt, 8 sampled poses)", 8 / statistics.median(times), "garments/s"))

    load = os.getloadavg()[0]
    print(f"\nphysdrape drape benchmark — checkpoint {checkpoint}, {args.threads} torch thread(s), "
          f"median of {args.repeats}, load average {load:.1f} on {os.cpu_count()} cores\n")
    width = max(len(r[0]) for r in rows)
    print(f"| {'measurement':<{width}} | {'value':>8} | unit       |")
    print(f"|{'-' * (width + 2)}|{'-' * 10}|------------|")
    for name, value, unit in rows:
        print(f"| {name:<{width}} | {value:8.2f} | {unit:<10} |")
    print("\nwarm drape phases [s]: " + ", ".join(f"{k[:-2]} {v:.3f}" for k, v in phases.items()))


if __name__ == "__main__":
    main()

"""Body-model timings: Anny load (cached, and optionally the first-ever build) and the forward
pass per batch of (shape, pose), medians over repeats.

    python bench/bench_body.py [--repeats 20] [--threads 1] [--first-build]

--first-build rebuilds Anny's model data in a temporary cache directory (slow: what a first-ever
use of the body costs).
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile

import torch
from timing import median_ms

LOAD_SNIPPET = (
    "import time; t = time.perf_counter(); from physdrape.body.anny_body import AnnyBody; "
    "b = AnnyBody(); print(time.perf_counter() - t)"
)


def time_load(env: dict) -> float:
    out = subprocess.run([sys.executable, "-c", LOAD_SNIPPET], env=env, capture_output=True, text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--repeats", type=int, default=20)
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--first-build", action="store_true")
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([os.path.join(os.path.dirname(__file__), "..", "src"), env.get("PYTHONPATH", "")])
    env["OMP_NUM_THREADS"] = str(args.threads)

    rows = []
    if args.first_build:
        with tempfile.TemporaryDirectory() as tmp:
            rows.append(("Anny first build (empty cache, new process)", time_load(dict(env, ANNY_CACHE_DIR=tmp)), ""))
    rows.append(("Anny load from cache (new process, incl. imports)", time_load(env), ""))

    from physdrape.body.anny_body import get_anny_body
    from physdrape.body.poses import arm_torso_penetration, sample_poses
    from physdrape.body.shapes import sample_shapes

    body = get_anny_body()
    for dtype in (torch.float32, torch.float64):
        for B in (1, 8):
            shape = sample_shapes(B, seed=0, dtype=dtype)
            pose = sample_poses(body, B, seed=0, dtype=dtype)
            t = median_ms(lambda: body(shape, pose), args.repeats, warmup=2) / 1e3
            rows.append((f"Anny forward B={B} {str(dtype)[6:]}", t, f"{1e3 * t / B:.2f} ms/body"))
            if dtype == torch.float32:
                with torch.no_grad():
                    t = median_ms(lambda: body(shape, pose), args.repeats, warmup=2) / 1e3
                rows.append((f"Anny forward B={B} float32 no_grad", t, f"{1e3 * t / B:.2f} ms/body"))
    st = body(body.default_shape(8), sample_poses(body, 8, seed=1))
    t = median_ms(lambda: arm_torso_penetration(st, body), max(3, args.repeats // 4), warmup=2) / 1e3
    rows.append(("arm_torso_penetration B=8", t, f"{1e3 * t / 8:.1f} ms/body"))
    t = median_ms(lambda: sample_poses(body, 8, seed=2), 3, warmup=2) / 1e3
    rows.append(("sample_poses 8 (with rejection)", t, f"{1e3 * t / 8:.1f} ms/pose"))
    t = median_ms(lambda: body.hm08_verts(body.default_shape(1)), args.repeats, warmup=2) / 1e3
    rows.append(("hm08_verts B=1 (19,158 verts)", t, ""))

    print(f"torch {torch.__version__}, threads {torch.get_num_threads()}, {body.num_verts} verts, "
          f"{body.num_faces} faces, {body.num_joints} joints")
    print(f"| {'what':<52} | {'median [ms]':>11} | {'':<14} |")
    print(f"|{'-' * 54}|{'-' * 13}|{'-' * 16}|")
    for name, t, extra in rows:
        print(f"| {name:<52} | {1e3 * t:>11.2f} | {extra:<14} |")


if __name__ == "__main__":
    main()

"""Benchmark: body-surface queries (Warp BVH) and the kinematic-init transfer, on this CPU.

Prints one table: Warp kernel compile (one-time) and module load, BVH build and refit, queries of
5k garment-like points (closest point + normal + signed distance + inside), the brute-force torch
reference at one size, and SkinningTransfer fit/apply for a 5k-vertex garment.

Body: the Anny canonical body (``physdrape.body.anny_body``) when importable and cached, else a
synthetic capsule of a similar size (the table says which).

    .venv/bin/python bench/bench_queries.py [--body auto|anny|synthetic] [--repeats 15] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np
import torch
from timing import median_ms


def median_ms_nowarm(fn, repeats):
    return median_ms(fn, repeats, warmup=0)

from physdrape.geometry.closest_point import closest_point_on_triangle
from physdrape.geometry.proximity import BodySurface, SignMethod


def load_body(kind: str) -> tuple[torch.Tensor, torch.Tensor, str]:
    if kind in ("auto", "anny"):
        try:
            from physdrape.body.anny_body import AnnyBody

            t0 = time.perf_counter()
            body = AnnyBody()
            verts = body.canonical_verts(dtype=torch.float64)
            faces = torch.as_tensor(body.faces, dtype=torch.int64)
            return verts, faces, f"Anny canonical body (loaded in {time.perf_counter() - t0:.1f} s)"
        except Exception as err:  # noqa: BLE001  (any failure -> synthetic fallback, reported)
            if kind == "anny":
                raise
            reason = f"{type(err).__name__}: {err}"[:80]
    else:
        reason = "requested"
    import trimesh

    mesh = trimesh.creation.capsule(height=1.2, radius=0.15, count=[90, 160])
    verts = torch.tensor(mesh.vertices, dtype=torch.float64)
    return verts, torch.tensor(mesh.faces, dtype=torch.int64), f"synthetic capsule (Anny unavailable: {reason})"


def garment_points(verts: torch.Tensor, faces: torch.Tensor, n: int, seed: int = 0) -> torch.Tensor:
    """Points like a garment's: on random body triangles, offset -1 cm .. +4 cm along the normal."""
    g = torch.Generator().manual_seed(seed)
    tri = verts[faces]
    area = torch.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0], dim=-1)
    f = torch.multinomial(area.norm(dim=-1), n, replacement=True, generator=g)
    w = -torch.log(torch.rand(n, 3, generator=g, dtype=verts.dtype))
    w = w / w.sum(-1, keepdim=True)
    nrm = area[f] / area[f].norm(dim=-1, keepdim=True)
    offset = torch.rand(n, 1, generator=g, dtype=verts.dtype) * 0.05 - 0.01
    return (tri[f] * w[..., None]).sum(1) + offset * nrm


def brute_force(points: torch.Tensor, verts: torch.Tensor, faces: torch.Tensor, chunk: int = 32):
    """Pure-torch reference: exact closest point over all triangles + generalized winding number."""
    tri = verts[faces]
    out_d, out_wn = [], []
    for s in range(0, len(points), chunk):
        x = points[s:s + chunk, None]
        p, _ = closest_point_on_triangle(x, tri[None, :, 0], tri[None, :, 1], tri[None, :, 2])
        out_d.append((x - p).norm(dim=-1).min(1).values)
        a, b, c = tri[None, :, 0] - x, tri[None, :, 1] - x, tri[None, :, 2] - x
        la, lb, lc = a.norm(dim=-1), b.norm(dim=-1), c.norm(dim=-1)
        num = (a * torch.cross(b, c, dim=-1)).sum(-1)
        den = la * lb * lc + (a * b).sum(-1) * lc + (b * c).sum(-1) * la + (c * a).sum(-1) * lb
        out_wn.append(torch.atan2(num, den).sum(-1) / (2 * np.pi))
    return torch.cat(out_d), torch.cat(out_wn)


_COMPILE_SNIPPET = """
import time, torch
t0 = time.perf_counter()
from physdrape.geometry.proximity import query_body_surface
v = torch.tensor([[0., 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1]], dtype=torch.float64)
f = torch.tensor([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
query_body_surface(torch.rand(4, 3, dtype=torch.float64), v, f)
print(time.perf_counter() - t0)
"""


def first_use_seconds(fresh_cache: bool) -> float:
    """Wall time of import + first query in a new process (fresh or warm Warp kernel cache)."""
    env = dict(os.environ)
    with tempfile.TemporaryDirectory() as cache:
        if fresh_cache:
            env["WARP_CACHE_PATH"] = cache
        out = subprocess.run([sys.executable, "-c", _COMPILE_SNIPPET], env=env, capture_output=True, text=True,
                             check=True)
    return float(out.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--body", choices=["auto", "anny", "synthetic"], default="auto")
    parser.add_argument("--num-points", type=int, default=5000)
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (1 was fastest on this machine)")
    parser.add_argument("--skip-compile", action="store_true", help="skip the fresh-kernel-cache subprocess")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)

    rows: list[tuple[str, str]] = []
    if not args.skip_compile:
        cold, warm = first_use_seconds(True), first_use_seconds(False)
        rows.append(("first use, new process, empty Warp kernel cache (compile)", f"{cold * 1e3:9.0f} ms"))
        rows.append(("first use, new process, warm kernel cache (import+load)", f"{warm * 1e3:9.0f} ms"))

    verts, faces, body_name = load_body(args.body)
    n = args.num_points
    x64 = garment_points(verts, faces, n)
    moved = verts + 0.003 * torch.randn(verts.shape, generator=torch.Generator().manual_seed(1), dtype=verts.dtype)

    for method in SignMethod:
        surface = BodySurface(verts, faces, sign_method=method)
        surface.query(x64)  # first call: kernel module load, one per process
        rows.append((f"[{method.value}] BodySurface() incl. topology precompute",
                     f"{median_ms_nowarm(lambda: BodySurface(verts, faces, sign_method=method), args.repeats):9.2f} ms"))
        rows.append((f"[{method.value}] BVH rebuild (same topology)",
                     f"{median_ms_nowarm(lambda: surface._build(verts[None]), args.repeats):9.2f} ms"))
        rows.append((f"[{method.value}] update() = refit",
                     f"{median_ms_nowarm(lambda: surface.update(moved), args.repeats):9.2f} ms"))
        surface.update(verts)
        for dtype in (torch.float32, torch.float64):
            for threads in (1, 2):  # side by side: the BVH search on one thread, or split over two
                s = BodySurface(verts.to(dtype), faces, sign_method=method, search_threads=threads)
                x = x64.to(dtype)
                s.query(x)
                rows.append((f"[{method.value}] query {n} pts, {str(dtype)[6:]}, {threads} search thread(s)",
                             f"{median_ms_nowarm(lambda: s.query(x), args.repeats):9.2f} ms"))
        x32 = x64.float().contiguous()
        body_idx = torch.zeros(n, dtype=torch.int32)
        rows.append((f"[{method.value}]   of which Warp BVH search",
                     f"{median_ms_nowarm(lambda: surface.search(x32, body_idx), args.repeats):9.2f} ms"))

    # Batch of 4 bodies (B, N, 3).
    batch = torch.stack([verts, moved, verts * 1.02, moved * 0.98])
    surface_b = BodySurface(batch, faces)
    xb = torch.stack([x64] * 4)
    surface_b.query(xb)
    rows.append((f"[winding_number] query 4 bodies x {n} pts, float64",
                 f"{median_ms_nowarm(lambda: surface_b.query(xb), max(3, args.repeats // 3)):9.2f} ms"))

    # Brute-force reference on a subset, extrapolated.
    sub = 200
    t0 = time.perf_counter()
    brute_force(x64[:sub], verts, faces)
    brute = (time.perf_counter() - t0) * n / sub
    rows.append((f"brute-force torch (closest + winding), {sub} pts x{n // sub} extrapolated",
                 f"{brute * 1e3:9.0f} ms"))

    # SkinningTransfer: a 'garment' = the body triangles of a band around the torso, pushed out 1 cm.
    from physdrape.body.skinning_transfer import SkinningTransfer
    from physdrape.body.model import BodyState

    centroid_y = verts[faces].mean(1)[:, 1]
    lo, hi = torch.quantile(centroid_y, 0.45), torch.quantile(centroid_y, 0.75)
    band = faces[(centroid_y > lo) & (centroid_y < hi)]
    used, g_faces = torch.unique(band, return_inverse=True)
    normals = BodySurface(verts, faces).query(verts[used]).normal
    g_verts = verts[used] + 0.01 * normals
    t0 = time.perf_counter()
    transfer = SkinningTransfer.fit(verts, faces, g_verts, g_faces)
    fit_ms = (time.perf_counter() - t0) * 1e3
    rows.append((f"SkinningTransfer.fit, garment {len(g_verts)} verts", f"{fit_ms:9.0f} ms"))
    for b in (1, 8):
        eye = torch.eye(4, dtype=verts.dtype).expand(b, len(verts), 4, 4)
        state = BodyState(verts=verts.expand(b, -1, -1), faces=faces, normals=verts.expand(b, -1, -1),
                          rest_verts=verts.expand(b, -1, -1), vertex_transforms=eye)
        transfer.apply(state)
        rows.append((f"SkinningTransfer.apply, B={b}, float64, "
                     f"{transfer.weights.values().numel() / len(g_verts):.0f} influences/vertex",
                     f"{median_ms_nowarm(lambda: transfer.apply(state), args.repeats):9.2f} ms"))

    print(f"body: {body_name}: {verts.shape[0]} verts, {faces.shape[0]} faces; "
          f"torch threads {torch.get_num_threads()}; medians of {args.repeats}")
    width = max(len(r[0]) for r in rows)
    print(f"{'what':<{width}}  {'time':>12}")
    for name, value in rows:
        print(f"{name:<{width}}  {value:>12}")


if __name__ == "__main__":
    main()

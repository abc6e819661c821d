"""Small procedural meshes for examples, tests and benchmarks (metres, y-up)."""

from __future__ import annotations

import numpy as np


def grid_sheet(rows: int, cols: int, *, width: float = 0.5, height: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """A flat rectangular sheet in the xz-plane (y = 0), split into right triangles.

    Args:
        rows, cols: vertices along z and x (each ≥ 2).
        width, height: extent along x and z [m].
    Returns:
        verts (rows·cols, 3) float64, faces (2(rows−1)(cols−1), 3) int64, normals along +y.
    """
    if rows < 2 or cols < 2:
        raise ValueError(f"a sheet needs at least 2×2 vertices, got {rows}×{cols}")
    xs, zs = np.meshgrid(np.linspace(0.0, width, cols), np.linspace(0.0, height, rows))
    verts = np.stack([xs.ravel(), np.zeros(xs.size), zs.ravel()], axis=1)
    idx = np.arange(rows * cols).reshape(rows, cols)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    # Alternate the diagonal so the sheet has no preferred shear direction.
    flip = ((np.arange(rows - 1)[:, None] + np.arange(cols - 1)[None, :]) % 2).ravel().astype(bool)
    tri1 = np.where(flip[:, None], np.stack([a, d, b], 1), np.stack([a, c, b], 1))
    tri2 = np.where(flip[:, None], np.stack([a, c, d], 1), np.stack([b, c, d], 1))
    return verts, np.concatenate([tri1, tri2]).astype(np.int64)


def open_cylinder(rings: int, segments: int, *, radius: float = 0.15, length: float = 0.4) -> tuple[np.ndarray, np.ndarray]:
    """An open tube along y (a sleeve or a skirt-like garment), two boundary loops.

    Returns:
        verts (rings·segments, 3) float64, faces (2(rings−1)·segments, 3) int64, normals outward.
    """
    if rings < 2 or segments < 3:
        raise ValueError(f"a tube needs ≥ 2 rings and ≥ 3 segments, got {rings}, {segments}")
    angle = np.linspace(0.0, 2.0 * np.pi, segments, endpoint=False)
    ys = np.linspace(length, 0.0, rings)
    verts = np.stack(
        [np.tile(radius * np.cos(angle), rings), np.repeat(ys, segments), np.tile(radius * np.sin(angle), rings)], axis=1
    )
    idx = np.arange(rings * segments).reshape(rings, segments)
    nxt = np.roll(idx, -1, axis=1)
    a, b, c, d = idx[:-1].ravel(), nxt[:-1].ravel(), idx[1:].ravel(), nxt[1:].ravel()
    faces = np.concatenate([np.stack([a, b, c], 1), np.stack([b, d, c], 1)])
    return verts, faces.astype(np.int64)

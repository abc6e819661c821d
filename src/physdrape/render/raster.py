"""A small numpy z-buffer rasteriser: no OpenGL, no display.

Orthographic camera looking along −z (+z towards the camera), per-pixel barycentric interpolation
of vertex normals and colours, two-sided Lambert shading, supersampling.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from physdrape.garments.numpy_geometry import vertex_normals
from physdrape.render.colors import BACKGROUND_RGB

__all__ = ["project", "rasterise", "render_view", "yaw_rotation"]


def yaw_rotation(yaw_deg: float) -> np.ndarray:
    """Rotation about +y by `yaw_deg` [deg], shape (3, 3); rows act on column vectors (v @ R.T)."""
    yaw = math.radians(yaw_deg)
    return np.array([[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]])


def rasterise(screen: np.ndarray, faces: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer rasterisation of triangles.

    Args:
        screen: vertex positions in pixels (col, row) and depth (smaller = nearer), shape (N, 3).
        faces: triangles (F, 3) int.
        height, width: image size [px].

    Returns:
        face_id (H, W) int64 (−1 = background) and barycentrics (H, W, 3).
    """
    tri = screen[faces]  # (F, 3, 3)
    lo = np.floor(tri[:, :, :2].min(1)).astype(np.int64)
    hi = np.ceil(tri[:, :, :2].max(1)).astype(np.int64)
    size = (hi - lo).max(1) + 1
    visible = (hi[:, 0] >= 0) & (hi[:, 1] >= 0) & (lo[:, 0] < width) & (lo[:, 1] < height)
    best_pix, best_depth, best_face, best_bary = [], [], [], []
    k = 4
    remaining = visible.copy()
    while remaining.any():
        group = np.flatnonzero(remaining & (size <= k))
        remaining[group] = False
        if group.size:
            # process in slices so the candidate arrays stay small
            for s in range(0, group.size, max(1, 2_000_000 // (k * k))):
                g = group[s:s + max(1, 2_000_000 // (k * k))]
                dx, dy = np.meshgrid(np.arange(k), np.arange(k))
                px = lo[g, 0, None] + dx.reshape(1, -1)
                py = lo[g, 1, None] + dy.reshape(1, -1)
                cx, cy = px + 0.5, py + 0.5
                a, b, c = tri[g, 0], tri[g, 1], tri[g, 2]
                den = (b[:, 1] - c[:, 1]) * (a[:, 0] - c[:, 0]) + (c[:, 0] - b[:, 0]) * (a[:, 1] - c[:, 1])
                ok_den = np.abs(den) > 1e-12
                den = np.where(ok_den, den, 1.0)[:, None]
                w0 = ((b[:, 1, None] - c[:, 1, None]) * (cx - c[:, 0, None]) + (c[:, 0, None] - b[:, 0, None]) * (cy - c[:, 1, None])) / den
                w1 = ((c[:, 1, None] - a[:, 1, None]) * (cx - c[:, 0, None]) + (a[:, 0, None] - c[:, 0, None]) * (cy - c[:, 1, None])) / den
                w2 = 1.0 - w0 - w1
                eps = -1e-9
                inside = (w0 >= eps) & (w1 >= eps) & (w2 >= eps) & ok_den[:, None]
                inside &= (px >= 0) & (px < width) & (py >= 0) & (py < height)
                fi, ci = np.nonzero(inside)
                if fi.size == 0:
                    continue
                bary = np.stack([w0[fi, ci], w1[fi, ci], w2[fi, ci]], 1)
                depth = (bary * tri[g[fi], :, 2]).sum(1)
                best_pix.append(py[fi, ci] * width + px[fi, ci])
                best_depth.append(depth)
                best_face.append(g[fi])
                best_bary.append(bary)
        k *= 2
    face_id = np.full(height * width, -1, np.int64)
    bary_img = np.zeros((height * width, 3))
    if best_pix:
        pix, depth = np.concatenate(best_pix), np.concatenate(best_depth)
        face, bary = np.concatenate(best_face), np.concatenate(best_bary)
        order = np.lexsort((depth, pix))
        pix, face, bary = pix[order], face[order], bary[order]
        first = np.ones(pix.size, bool)
        first[1:] = pix[1:] != pix[:-1]
        face_id[pix[first]] = face[first]
        bary_img[pix[first]] = bary[first]
    return face_id.reshape(height, width), bary_img.reshape(height, width, 3)


def _camera(frame: tuple[float, float, float, float], height: int) -> tuple[float, float, float, int]:
    """(x_left [m], y_top [m], scale [px/m], width [px]) of a view `height` px high showing `frame`
    (x_min, x_max, y_min, y_max) [m] with a 3 % margin."""
    x0, x1, y0, y1 = frame
    pad = 0.03 * max(x1 - x0, y1 - y0)
    x0, x1, y0, y1 = x0 - pad, x1 + pad, y0 - pad, y1 + pad
    scale = height / (y1 - y0)
    return x0, y1, scale, max(8, round((x1 - x0) * scale))


def project(points: np.ndarray, *, yaw_deg: float, size: int, frame: tuple[float, float, float, float],
            supersample: int = 2) -> np.ndarray:
    """Where points (N, 3) [m] land in the image `render_view` makes with the same yaw, size, frame
    and supersampling: (N, 3) = image column and row [px] (pixel k spans [k, k + 1)) and the depth
    along the view [m] (larger = nearer the camera)."""
    v = np.asarray(points, np.float64) @ yaw_rotation(yaw_deg).T
    x0, y1, scale, _ = _camera(frame, size * supersample)
    return np.stack([(v[:, 0] - x0) * scale / supersample, (y1 - v[:, 1]) * scale / supersample, v[:, 2]], 1)


def render_view(meshes: Sequence[dict], *, yaw_deg: float = 0.0, size: int = 512,
                frame: tuple[float, float, float, float] | None = None, supersample: int = 2) -> np.ndarray:
    """Render meshes seen from the front (+z towards the camera), rotated by `yaw_deg` about y.

    Args:
        meshes: dicts with "verts" (N, 3) [m], "faces" (F, 3), "colors" (N, 3) in [0, 1], an
            optional "face_colors" (F, 3) (NaN rows = use the vertex colours) and "cull": True for
            closed outward-wound meshes (back faces skipped).
        frame: (x_min, x_max, y_min, y_max) [m] of the view after rotation; default: all meshes.
        size: output height [px]; the width follows the frame's aspect ratio.

    Returns:
        RGB image (H, W, 3) float in [0, 1].
    """
    rot = yaw_rotation(yaw_deg)
    verts, faces, colors, fcolors, normals = [], [], [], [], []
    offset = 0
    for m in meshes:
        v = np.asarray(m["verts"], np.float64) @ rot.T
        f = np.asarray(m["faces"], np.int64)
        keep = np.ones(len(f), bool)
        if m.get("cull"):  # closed, outward-wound mesh: drop faces turned away from the camera
            keep = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])[:, 2] > 0
        verts.append(v)
        faces.append(f[keep] + offset)
        colors.append(np.broadcast_to(np.asarray(m["colors"], np.float64), v.shape))
        fc = m.get("face_colors")
        fcolors.append(np.full((int(keep.sum()), 3), np.nan) if fc is None else np.asarray(fc, np.float64)[keep])
        normals.append(vertex_normals(v, f))
        offset += len(v)
    v, f = np.concatenate(verts), np.concatenate(faces)
    col, fcol, nrm = np.concatenate(colors), np.concatenate(fcolors), np.concatenate(normals)
    if frame is None:
        frame = (v[:, 0].min(), v[:, 0].max(), v[:, 1].min(), v[:, 1].max())
    x0, y1, scale, width = _camera(frame, size * supersample)
    height = size * supersample
    screen = np.stack([(v[:, 0] - x0) * scale, (y1 - v[:, 1]) * scale, -v[:, 2]], 1)
    face_id, bary = rasterise(screen, f, height, width)
    hit = face_id >= 0
    fid = face_id[hit]
    tri = f[fid]
    w = bary[hit][:, :, None]
    n = (nrm[tri] * w).sum(1)
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    c = (col[tri] * w).sum(1)
    override = ~np.isnan(fcol[fid, 0])
    c[override] = fcol[fid[override]]
    light = np.array([0.3, 0.4, 1.0])
    light /= np.linalg.norm(light)
    lambert = np.abs(n @ light)  # two-sided: garments are open sheets
    shade = 0.35 + 0.65 * lambert
    img = np.tile(BACKGROUND_RGB, (height * width, 1)).reshape(height, width, 3)
    img[hit] = np.clip(c * shade[:, None], 0, 1)
    if supersample > 1:
        h2, w2 = height // supersample, width // supersample
        img = img[: h2 * supersample, : w2 * supersample].reshape(h2, supersample, w2, supersample, 3).mean((1, 3))
    return img

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
from physdrape.warp_runtime import defined_once, warp

__all__ = ["project", "rasterise", "render_view", "yaw_rotation"]


def yaw_rotation(yaw_deg: float) -> np.ndarray:
    """Rotation about +y by `yaw_deg` [deg], shape (3, 3); rows act on column vectors (v @ R.T)."""
    yaw = math.radians(yaw_deg)
    return np.array([[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]])


def rasterise(screen: np.ndarray, faces: np.ndarray, height: int, width: int) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer rasterisation of triangles (three launches of one Warp kernel: each triangle's
    pixels lower the depth buffer, then the nearest triangles claim their pixels, then the winner
    writes its face and barycentrics; of equally near triangles the one of the smallest
    `_claim_order` wins, so the image does not depend on the order of the threads).

    Args:
        screen: vertex positions in pixels (col, row) and depth (smaller = nearer), shape (N, 3).
        faces: triangles (F, 3) int.
        height, width: image size [px].

    Returns:
        face_id (H, W) int64 (−1 = background) and barycentrics (H, W, 3).
    """
    wp, kernel = warp(), _raster_kernel()
    pixels = height * width
    face_id = np.full(pixels, -1, np.int64)
    bary = np.zeros((pixels, 3))
    faces = np.asarray(faces, np.int64)
    if len(faces) == 0 or pixels == 0:
        return face_id.reshape(height, width), bary.reshape(height, width, 3)
    args = [wp.array(np.ascontiguousarray(screen, np.float64), dtype=wp.vec3d, device="cpu"),
            wp.array(np.ascontiguousarray(faces, np.int32), dtype=wp.int32, device="cpu"),
            wp.array(_claim_order(screen, faces), dtype=wp.int32, device="cpu"), int(width), int(height)]
    depth = wp.array(np.full(pixels, np.inf), dtype=wp.float64, device="cpu")
    winner = wp.array(np.full(pixels, np.iinfo(np.int32).max, np.int32), dtype=wp.int32, device="cpu")
    out_face = wp.array(face_id, dtype=wp.int64, device="cpu")
    out_bary = wp.array(bary, dtype=wp.vec3d, device="cpu")
    for stage in range(3):
        wp.launch(kernel, dim=len(faces), inputs=[*args, stage, depth, winner, out_face, out_bary], device="cpu")
    return out_face.numpy().reshape(height, width), out_bary.numpy().reshape(height, width, 3)


def _claim_order(screen: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Which of equally near triangles takes a pixel: smaller first, by the side of the square
    (4, 8, 16, … px) that holds the triangle's pixel box, then by face index, (F,) int32."""
    tri = np.asarray(screen, np.float64)[faces][:, :, :2]
    size = (np.ceil(tri.max(1)) - np.floor(tri.min(1))).max(1) + 1
    rank = np.ceil(np.log2(np.maximum(size, 4) / 4)).astype(np.int64)
    return (rank * len(faces) + np.arange(len(faces))).astype(np.int32)


@defined_once
def _raster_kernel():
    """The rasteriser's kernel (`rasterise`), defined on first use."""
    wp = warp()
    f64 = wp.float64

    @wp.kernel(enable_backward=False)
    def raster_kernel(screen: wp.array(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                      order: wp.array(dtype=wp.int32), width: int, height: int, stage: int,
                      depth: wp.array(dtype=wp.float64), winner: wp.array(dtype=wp.int32),
                      face_id: wp.array(dtype=wp.int64), bary: wp.array(dtype=wp.vec3d)):
        f = wp.tid()
        a = screen[faces[f, 0]]
        b = screen[faces[f, 1]]
        c = screen[faces[f, 2]]
        den = (b[1] - c[1]) * (a[0] - c[0]) + (c[0] - b[0]) * (a[1] - c[1])
        if wp.abs(den) <= f64(1e-12):
            return
        x_lo = wp.max(int(wp.floor(wp.min(wp.min(a[0], b[0]), c[0]))), 0)
        x_hi = wp.min(int(wp.ceil(wp.max(wp.max(a[0], b[0]), c[0]))), width - 1)
        y_lo = wp.max(int(wp.floor(wp.min(wp.min(a[1], b[1]), c[1]))), 0)
        y_hi = wp.min(int(wp.ceil(wp.max(wp.max(a[1], b[1]), c[1]))), height - 1)
        eps = f64(-1e-9)
        for py in range(y_lo, y_hi + 1):
            cy = f64(py) + f64(0.5)
            for px in range(x_lo, x_hi + 1):
                cx = f64(px) + f64(0.5)
                w0 = ((b[1] - c[1]) * (cx - c[0]) + (c[0] - b[0]) * (cy - c[1])) / den
                w1 = ((c[1] - a[1]) * (cx - c[0]) + (a[0] - c[0]) * (cy - c[1])) / den
                w2 = f64(1.0) - w0 - w1
                if w0 >= eps and w1 >= eps and w2 >= eps:
                    z = w0 * a[2] + w1 * b[2] + w2 * c[2]
                    p = py * width + px
                    if stage == 0:
                        wp.atomic_min(depth, p, z)
                    elif stage == 1:
                        if z == depth[p]:
                            wp.atomic_min(winner, p, order[f])
                    elif z == depth[p] and order[f] == winner[p]:
                        face_id[p] = wp.int64(f)
                        bary[p] = wp.vec3d(w0, w1, w2)

    return raster_kernel


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
    hit = np.flatnonzero(face_id >= 0)
    fid = face_id.ravel()[hit]
    tri = f[fid]
    w = bary.reshape(-1, 3)[hit]
    n = np.einsum("pk,pkc->pc", w, nrm[tri])
    n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
    c = np.einsum("pk,pkc->pc", w, col[tri])
    override = ~np.isnan(fcol[fid, 0])
    c[override] = fcol[fid[override]]
    light = np.array([0.3, 0.4, 1.0])
    light /= np.linalg.norm(light)
    lambert = np.abs(n @ light)  # two-sided: garments are open sheets
    shade = 0.35 + 0.65 * lambert
    img = np.empty((height * width, 3))
    img[:] = BACKGROUND_RGB
    img[hit] = np.clip(c * shade[:, None], 0, 1)
    img = img.reshape(height, width, 3)
    if supersample > 1:  # the mean of each block of supersample × supersample pixels
        h2, w2 = height // supersample, width // supersample
        img = sum(img[i: h2 * supersample: supersample, j: w2 * supersample: supersample]
                  for i in range(supersample) for j in range(supersample)) / supersample ** 2
    return img

"""Headless pictures of drapes: a small numpy z-buffer rasteriser plus matplotlib for layout.

- `render_result`: shaded body + garment, front and three-quarter views ("shaded"), or the
  per-vertex residual force ‖F_int‖/(m g) as a heatmap with penetrating faces (centroid inside
  the body) in red ("residual"; the paper's Fig. 1).
- `convergence_figure`: energy and total force over the stretching solver steps (paper Fig. 3).
- `material_sweep_figure`: the same garment and pose in several fabrics side by side (Fig. 6).
- `compose_gallery`: tiles of those PNGs (``physdrape drape --figures`` writes gallery.png;
  docs/gallery.png is that file from ``physdrape drape --pose stand --figures --out /tmp/gallery``
  with the bundled model).

No OpenGL, no display: orthographic camera, per-pixel barycentric interpolation of vertex
normals and colours, 2× supersampling.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from physdrape.garments.numpy_geometry import vertex_normals

__all__ = [
    "compose_gallery",
    "convergence_figure",
    "material_sweep_figure",
    "rasterise",
    "render_result",
    "render_view",
]

BODY_RGB = np.array([0.80, 0.74, 0.68])
GARMENT_RGB = np.array([0.27, 0.47, 0.78])
PENETRATION_RGB = np.array([0.90, 0.05, 0.05])
BACKGROUND_RGB = np.array([1.0, 1.0, 1.0])


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
    yaw = math.radians(yaw_deg)
    rot = np.array([[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]])
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
    x0, x1, y0, y1 = frame
    pad = 0.03 * max(x1 - x0, y1 - y0)
    x0, x1, y0, y1 = x0 - pad, x1 + pad, y0 - pad, y1 + pad
    height = size * supersample
    scale = height / (y1 - y0)
    width = max(8, round((x1 - x0) * scale))
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


def _frame(result, yaw_deg: float) -> tuple[float, float, float, float]:
    """Upper-body frame: from below the garment hem to the top of the head, body-wide."""
    yaw = math.radians(yaw_deg)
    rot = np.array([[math.cos(yaw), 0, math.sin(yaw)], [0, 1, 0], [-math.sin(yaw), 0, math.cos(yaw)]])
    g = np.asarray(result.verts) @ rot.T
    b = np.asarray(result.body_verts) @ rot.T
    y_lo = g[:, 1].min() - 0.12
    band = b[b[:, 1] >= y_lo]
    pts = np.concatenate([g, band])
    return pts[:, 0].min(), pts[:, 0].max(), y_lo, b[:, 1].max()


def _meshes(result, mode: str) -> list[dict]:
    body = {"verts": result.body_verts, "faces": result.body_faces, "colors": BODY_RGB, "cull": True}
    if mode == "shaded":
        return [body, {"verts": result.verts, "faces": result.faces, "colors": GARMENT_RGB}]
    import matplotlib

    cmap = matplotlib.colormaps["viridis"]
    value = np.log10(np.maximum(np.asarray(result.vertex_residual, np.float64), 1e-3))
    colors = cmap(np.clip((value + 3.0) / 5.0, 0, 1))[:, :3]  # 1e-3 … 1e2 of a vertex's weight
    face_colors = np.full((len(result.faces), 3), np.nan)
    face_colors[np.asarray(result.inside_faces, bool)] = PENETRATION_RGB
    return [body, {"verts": result.verts, "faces": result.faces, "colors": colors, "face_colors": face_colors}]


def _figure(ncols: int, aspect: float, height_in: float = 4.5):
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, ncols, figsize=(height_in * aspect * ncols + 0.8, height_in + 0.6), squeeze=False)
    return fig, axes[0]


def _save(fig, path: str | os.PathLike) -> Path:
    import io

    import matplotlib.pyplot as plt

    from physdrape.atomic import write_bytes

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    plt.close(fig)
    path = Path(path)
    write_bytes(path, buf.getvalue())
    return path


def render_result(result, path: str | os.PathLike, *, mode: str = "shaded", size: int = 640,
                  views: Sequence[float] = (0.0, 40.0)) -> Path:
    """Write a PNG of a `DrapeResult`: body + garment from each yaw in `views` [deg].

    mode: "shaded" (plain colours) or "residual" (garment coloured by log10 ‖F_int‖/(m g),
    faces whose centroid is inside the body in red).
    """
    if mode not in ("shaded", "residual"):
        raise ValueError(f"unknown render mode {mode!r}; use 'shaded' or 'residual'")
    images = [render_view(_meshes(result, mode), yaw_deg=yaw, size=size, frame=_frame(result, yaw)) for yaw in views]
    aspect = max(im.shape[1] / im.shape[0] for im in images)
    fig, axes = _figure(len(images), aspect)
    for ax, im, yaw in zip(axes, images, views):
        ax.imshow(im)
        ax.set_axis_off()
        ax.set_title("front" if yaw == 0 else f"yaw {yaw:g}°", fontsize=10)
    m = result.metrics
    title = (f"{result.name}: E_strain {m['strain']:.3g} J, E_bend {m['bend']:.3g} J, "
             f"B2G {m['b2g_percent']:.2f} %")
    if mode == "residual":
        import matplotlib
        import matplotlib.pyplot as plt

        sm = plt.cm.ScalarMappable(cmap=matplotlib.colormaps["viridis"], norm=matplotlib.colors.Normalize(-3, 2))
        bar = fig.colorbar(sm, ax=list(axes), fraction=0.03, pad=0.02)
        bar.set_label("log10 residual force / vertex weight")
        title += f"; red: {int(np.sum(result.inside_faces))} faces inside the body"
    fig.suptitle(title, fontsize=10)
    return _save(fig, path)


def convergence_figure(result, path: str | os.PathLike) -> Path:
    """Energy E_strain + E_bend + E_grav [J] and total force Σ‖F_int + f̂‖ [N] per solver step
    (needs a result draped with keep_trace=True)."""
    conv = result.convergence
    if not conv:
        raise ValueError("this result has no solver trace: drape with keep_trace=True")
    fig, axes = _figure(2, 1.2, height_in=3.2)
    steps = np.arange(len(conv["energy"]))
    axes[0].plot(steps, conv["energy"], "o-", color="C0")
    axes[0].set_xlabel("solver step t (0 = GNN output)")
    axes[0].set_ylabel("E_strain + E_bend + E_grav [J]")
    axes[1].plot(steps, conv["force"], "o-", color="C3")
    axes[1].set_xlabel("solver step t (0 = GNN output)")
    axes[1].set_ylabel("Σ_i ‖F_int + f̂‖ [N]")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.grid(alpha=0.3)
    fig.suptitle(f"{result.name}: stretching solver convergence", fontsize=10)
    fig.tight_layout()
    return _save(fig, path)


def material_sweep_figure(results: Sequence, labels: Sequence[str], path: str | os.PathLike, *, size: int = 480,
                          yaw_deg: float = 30.0) -> Path:
    """The same garment and pose in several materials side by side (one view each, shared frame)."""
    if len(results) != len(labels) or not results:
        raise ValueError("give one label per result")
    frames = np.array([_frame(r, yaw_deg) for r in results])
    frame = (frames[:, 0].min(), frames[:, 1].max(), frames[:, 2].min(), frames[:, 3].max())
    images = [render_view(_meshes(r, "shaded"), yaw_deg=yaw_deg, size=size, frame=frame) for r in results]
    fig, axes = _figure(len(images), images[0].shape[1] / images[0].shape[0], height_in=4.0)
    for ax, im, r, label in zip(axes, images, results, labels):
        ax.imshow(im)
        ax.set_axis_off()
        mean_y = float(np.mean(r.verts[:, 1]))
        ax.set_title(f"{label}\nmean y {mean_y * 100:.2f} cm, E_strain {r.metrics['strain']:.3g} J", fontsize=9)
    fig.suptitle("material sweep (same garment, body and pose)", fontsize=10)
    return _save(fig, path)


def compose_gallery(pictures: Sequence[str | os.PathLike], path: str | os.PathLike, *, columns: int = 2) -> Path:
    """Tile existing PNGs (e.g. render, residual, convergence, materials) into one picture."""
    import matplotlib.image as mpimg

    images = [mpimg.imread(str(p))[..., :3] for p in pictures]
    rows = math.ceil(len(images) / columns)
    tiles = []
    for r in range(rows):
        row = images[r * columns:(r + 1) * columns]
        height = max(im.shape[0] for im in row)
        padded = []
        for im in row:
            canvas = np.ones((height, im.shape[1], 3), dtype=im.dtype)
            canvas[: im.shape[0]] = im
            padded.append(canvas)
        tiles.append(np.concatenate(padded, axis=1))
    full_width = max(t.shape[1] for t in tiles)
    tiles = [np.concatenate([t, np.ones((t.shape[0], full_width - t.shape[1], 3), t.dtype)], axis=1) for t in tiles]
    picture = np.concatenate(tiles, axis=0)
    import io

    from physdrape.atomic import write_bytes

    buf = io.BytesIO()
    mpimg.imsave(buf, np.clip(picture, 0, 1), format="png")
    path = Path(path)
    write_bytes(path, buf.getvalue())
    return path

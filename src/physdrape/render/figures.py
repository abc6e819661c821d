"""The pictures of drapes: renders, convergence, the material sweep and the gallery that tiles them.

Text has a fixed size in pixels whatever the render size, and every panel is at least as wide as its
captions, so captions never overlap; a render's height [px] is `size`, text bands come on top.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from physdrape.render.colors import BODY_RGB, PENETRATION_RGB, fabric_color, material_caption
from physdrape.render.hem import hem_azimuth, hem_drop, hem_loop
from physdrape.render.layout import Canvas, line_height, text_width
from physdrape.render.raster import project, render_view, yaw_rotation

__all__ = ["compose_gallery", "convergence_figure", "full_frame", "garment_frame", "material_sweep_figure",
           "render_result"]

PAD, GAP = 12, 16  # outer margin, space between panels [px]
TITLE_PT, TEXT_PT = 12.0, 10.0  # font sizes [pt]
VIEW_NAMES = {0.0: "front", 180.0: "back"}
HEM_RGB = (1.0, 0.80, 0.0)  # the hem line: gold, outlined in black


def full_frame(result, yaw_deg: float) -> tuple[float, float, float, float]:
    """(x_min, x_max, y_min, y_max) [m] of body and garment seen from `yaw_deg`: head to feet."""
    rot = yaw_rotation(yaw_deg)
    pts = np.concatenate([np.asarray(result.body_verts), np.asarray(result.verts)]) @ rot.T
    return pts[:, 0].min(), pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max()


def garment_frame(result, yaw_deg: float) -> tuple[float, float, float, float]:
    """From 12 cm below the garment's lowest point to the top of the head, as wide as what is in it."""
    rot = yaw_rotation(yaw_deg)
    g = np.asarray(result.verts) @ rot.T
    b = np.asarray(result.body_verts) @ rot.T
    y_lo = max(g[:, 1].min() - 0.12, b[:, 1].min())
    pts = np.concatenate([g, b[b[:, 1] >= y_lo]])
    return pts[:, 0].min(), pts[:, 0].max(), y_lo, b[:, 1].max()


def _meshes(result, mode: str) -> list[dict]:
    body = {"verts": result.body_verts, "faces": result.body_faces, "colors": BODY_RGB, "cull": True}
    if mode == "shaded":
        return [body, {"verts": result.verts, "faces": result.faces, "colors": fabric_color(result.material)}]
    import matplotlib

    cmap = matplotlib.colormaps["viridis"]
    value = np.log10(np.maximum(np.asarray(result.vertex_residual, np.float64), 1e-3))
    colors = cmap(np.clip((value + 3.0) / 5.0, 0, 1))[:, :3]  # 1e-3 … 1e2 of a vertex's weight
    face_colors = np.full((len(result.faces), 3), np.nan)
    face_colors[np.asarray(result.inside_faces, bool)] = PENETRATION_RGB
    return [body, {"verts": result.verts, "faces": result.faces, "colors": colors, "face_colors": face_colors}]


def _view_name(yaw: float) -> str:
    return VIEW_NAMES.get(float(yaw) % 360.0, f"yaw {yaw:g}°")


def _fit(text: str, size: float, width: float, *, bold: bool = False) -> str:
    """`text`, cut with an ellipsis to fit in `width` px."""
    if text_width(text, size, bold=bold) <= width:
        return text
    while len(text) > 1 and text_width(text + "…", size, bold=bold) > width:
        text = text[:-1]
    return text + "…"


def render_result(result, path: str | os.PathLike, *, mode: str = "shaded", size: int = 640,
                  views: Sequence[float] = (0.0, 180.0)) -> Path:
    """Write a PNG of a `DrapeResult`: body + garment, head to feet, seen from each yaw in `views` [deg]
    (front and back by default), side by side, each `size` px high under a caption band.

    mode: "shaded" (the garment in its fabric's colour, see `fabric_color`) or "residual" (garment
    coloured by log10 ‖F_int‖/(m g), faces whose centroid is inside the body in red).
    """
    if mode not in ("shaded", "residual"):
        raise ValueError(f"unknown render mode {mode!r}; use 'shaded' or 'residual'")
    images = [render_view(_meshes(result, mode), yaw_deg=yaw, size=size, frame=full_frame(result, yaw))
              for yaw in views]
    m = result.metrics
    name, constants = material_caption(result.material)
    lines = [(f"{result.name} [{result.pose}]", TITLE_PT, True),
             (f"{name}: {constants[0]}", TEXT_PT, False),
             (f"E_strain {m['strain']:.3g} J · E_bend {m['bend']:.3g} J · B2G {m['b2g_percent']:.2f} %",
              TEXT_PT, False)]
    if mode == "residual":
        inside = int(np.sum(result.inside_faces))
        lines.append((f"colour: log10 residual force / vertex weight; red: {inside} faces inside the body",
                      TEXT_PT, False))
    swatch = line_height(TEXT_PT) - 4
    bar_w = 64 if mode == "residual" else 0
    views_w = sum(im.shape[1] for im in images) + GAP * (len(images) - 1)
    text_w = max(text_width(s, pt, bold=b) for s, pt, b in lines) + swatch + 6
    width = 2 * PAD + max(views_w + bar_w, text_w)
    header = PAD + sum(line_height(pt) for _, pt, _ in lines) + line_height(TEXT_PT)
    canvas = Canvas(width, header + size + PAD)
    y = PAD
    for k, (text, pt, bold) in enumerate(lines):
        x = PAD
        if k == 1:
            canvas.swatch(PAD, y + 2, swatch, fabric_color(result.material))
            x += swatch + 6
        canvas.text(x, y, text, pt, bold=bold)
        y += line_height(pt)
    x = PAD + (width - 2 * PAD - views_w - bar_w) // 2
    for im, yaw in zip(images, views):
        canvas.text(x + im.shape[1] / 2, y, _view_name(yaw), TEXT_PT, ha="center")
        canvas.image(im, x, header)
        x += im.shape[1] + GAP
    if mode == "residual":
        import matplotlib

        cax = canvas.fig.add_axes(canvas.rect(x, header + 0.1 * size, 14, 0.8 * size))
        sm = matplotlib.cm.ScalarMappable(cmap=matplotlib.colormaps["viridis"], norm=matplotlib.colors.Normalize(-3, 2))
        canvas.fig.colorbar(sm, cax=cax).ax.tick_params(labelsize=8)
    return canvas.save(path)


def convergence_figure(result, path: str | os.PathLike) -> Path:
    """Energy E_strain + E_bend + E_grav [J] and total force Σ‖F_int + f̂‖ [N] per solver step
    (needs a result draped with keep_trace=True)."""
    conv = result.convergence
    if not conv:
        raise ValueError("this result has no solver trace: drape with keep_trace=True")
    import io

    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    from physdrape.atomic import write_bytes

    fig = Figure(figsize=(8.5, 3.8), dpi=110)
    FigureCanvasAgg(fig)
    axes = fig.subplots(1, 2)
    steps = np.arange(len(conv["energy"]))
    axes[0].plot(steps, conv["energy"], "o-", color="C0")
    axes[0].set_ylabel("E_strain + E_bend + E_grav [J]")
    axes[1].plot(steps, conv["force"], "o-", color="C3")
    axes[1].set_ylabel("Σ_i ‖F_int + f̂‖ [N]")
    axes[1].set_yscale("log")
    for ax in axes:
        ax.set_xlabel("solver step t (0 = GNN output)")
        ax.grid(alpha=0.3)
    fig.suptitle(f"{result.name} [{result.pose}]: stretching solver convergence", fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110, bbox_inches="tight")
    path = Path(path)
    write_bytes(path, buf.getvalue())
    return path


def _hem_line(ax, result, hem: np.ndarray, *, yaw_deg: float, size: int, frame) -> None:
    """Draw the hem of `result` on the image axes `ax` of its view: solid where it faces the camera,
    dotted behind the body."""
    from matplotlib import patheffects

    p = project(np.asarray(result.verts)[hem], yaw_deg=yaw_deg, size=size, frame=frame)
    loop = np.append(np.arange(len(hem)), 0)
    xy = p[loop, :2] - 0.5  # imshow puts pixel k's centre at k
    front = p[loop, 2] >= p[:, 2].mean()
    outline = [patheffects.withStroke(linewidth=3.2, foreground="black")]
    back = np.where(~front[:, None], xy, np.nan)
    ax.plot(back[:, 0], back[:, 1], ":", color=HEM_RGB, linewidth=1.0, alpha=0.7)
    near = np.where(front[:, None], xy, np.nan)
    ax.plot(near[:, 0], near[:, 1], "-", color=HEM_RGB, linewidth=1.6, path_effects=outline)


def _hem_profile(canvas: Canvas, results: Sequence, labels: Sequence[str], hems: list, box) -> None:
    """Each result's hem height relative to X_init [cm] against azimuth around the body, in its
    fabric colour, on one axes at pixel box (x, y, w, h)."""
    ax = canvas.fig.add_axes(canvas.rect(*box))
    for r, label, hem in zip(results, labels, hems):
        azimuth = hem_azimuth(r.x_init, hem)
        order = np.argsort(azimuth)
        azimuth, height = azimuth[order], -100.0 * hem_drop(r.verts, r.x_init, hem).drop[order]
        azimuth = np.concatenate([azimuth[-1:] - 360.0, azimuth, azimuth[:1] + 360.0])  # closed around the back
        height = np.concatenate([height[-1:], height, height[:1]])
        ax.plot(azimuth, height, color=fabric_color(r.material), linewidth=1.4, label=str(label))
    ax.axhline(0.0, color="0.5", linewidth=0.8, linestyle="--")
    ax.set_xlim(-180, 180)
    ax.set_xticks([-180, -90, 0, 90, 180], ["back", "wearer's right (−x)", "front (+z)", "wearer's left (+x)", "back"],
                  fontsize=8)
    ax.tick_params(labelsize=8)
    ax.set_ylabel("hem height − X_init [cm]", fontsize=8)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=min(len(results), 4), loc="upper center", frameon=False)


def material_sweep_figure(results: Sequence, labels: Sequence[str], path: str | os.PathLike, *, size: int = 480,
                          yaw_deg: float = 30.0, note: str | None = None) -> Path:
    """The same garment and pose in several materials side by side: one view each in one shared frame
    (head to below the hem), each `size` px high, its hem (`render.hem`) marked, and captioned below
    with its label, fabric colour, key constants, hem drop and bending and strain energies; under
    the views, the hems' height profiles on one chart. `note` is added to the title (e.g. how the
    drapes were made)."""
    if len(results) != len(labels) or not results:
        raise ValueError(f"give one label per result (got {len(labels)} labels for {len(results)} results)")
    frames = np.array([garment_frame(r, yaw_deg) for r in results])
    frame = (frames[:, 0].min(), frames[:, 1].max(), frames[:, 2].min(), frames[:, 3].max())
    images = [render_view(_meshes(r, "shaded"), yaw_deg=yaw_deg, size=size, frame=frame) for r in results]
    hems = [hem_loop(r.faces, r.x_init) for r in results]
    swatch = line_height(TITLE_PT) - 5
    captions = []
    for r, label, hem in zip(results, labels, hems):
        _, constants = material_caption(r.material)
        drop = hem_drop(r.verts, r.x_init, hem)
        captions.append([(str(label), TITLE_PT, True), *((c, TEXT_PT, False) for c in constants),
                         (f"hem drop {100 * drop.mean:.2f} cm (spread {100 * drop.spread:.2f})", TEXT_PT, False),
                         (f"E_bend {r.metrics['bend']:.3g} J · E_strain {r.metrics['strain']:.3g} J", TEXT_PT, False)])
    footnote = ["hem (gold): the garment's longest opening; hem drop: its mean fall below X_init (the skinned "
                "garment before physics), spread: the drop's standard deviation along the hem.",
                "E_bend, E_strain: the drape metrics, with the default (cotton) constants for every fabric, "
                "so they compare shapes, not stiffnesses."]
    panel_w = max(max(im.shape[1] for im in images),
                  *(text_width(s, pt, bold=b) + (swatch + 6) * b for cap in captions for s, pt, b in cap))
    title = (f"material sweep: {results[0].name} [{results[0].pose}], same body, pose and view (yaw {yaw_deg:g}°)"
             + (f"; {note}" if note else ""))
    width = max(2 * PAD + len(images) * panel_w + GAP * (len(images) - 1), 2 * PAD + text_width(title, TITLE_PT),
                2 * PAD + max(text_width(s, TEXT_PT) for s in footnote))
    top = PAD + line_height(TITLE_PT) + GAP // 2
    caption_h = sum(line_height(pt) for _, pt, _ in captions[0])
    chart_top = top + size + 6 + caption_h + GAP
    chart_h = max(160, size // 2)
    chart_left = PAD + 56  # room for the axis labels
    canvas = Canvas(width, chart_top + chart_h + 34 + len(footnote) * line_height(TEXT_PT) + PAD)
    canvas.text(PAD, PAD, title, TITLE_PT, bold=True)
    x0 = (width - len(images) * panel_w - GAP * (len(images) - 1)) // 2
    for k, (im, cap, r, hem) in enumerate(zip(images, captions, results, hems)):
        x = x0 + k * (panel_w + GAP)
        ax = canvas.image(im, x + (panel_w - im.shape[1]) // 2, top)
        _hem_line(ax, r, hem, yaw_deg=yaw_deg, size=size, frame=frame)
        ax.set_xlim(-0.5, im.shape[1] - 0.5)
        ax.set_ylim(im.shape[0] - 0.5, -0.5)
        y = top + size + 6
        for s, pt, bold in cap:
            if bold:
                canvas.swatch(x, y + 2, swatch, fabric_color(r.material))
                canvas.text(x + swatch + 6, y, s, pt, bold=True)
            else:
                canvas.text(x, y, s, pt)
            y += line_height(pt)
    _hem_profile(canvas, results, labels, hems, (chart_left, chart_top, width - chart_left - PAD - 24, chart_h))
    y = chart_top + chart_h + 34
    for line in footnote:
        canvas.text(PAD, y, line, TEXT_PT)
        y += line_height(TEXT_PT)
    return canvas.save(path)


def _read(path) -> np.ndarray:
    import matplotlib.image as mpimg

    return mpimg.imread(str(path))[..., :3]


def compose_gallery(pictures: Sequence[str | os.PathLike], path: str | os.PathLike, *, columns: int = 2,
                    heading: str | None = None, batch: Sequence[str | os.PathLike] = (),
                    batch_captions: Sequence[str] = ()) -> Path:
    """Tile PNGs into one picture: `pictures` (e.g. render, residual, convergence, materials) at their
    own size in rows of `columns`; then, when `batch` is given, every garment's render in a grid below
    (up to 4 columns, more from 17 garments on), scaled to the width of the tiles above, each captioned
    with its entry of `batch_captions` (e.g. "tshirt_3 [relaxed]"). `heading` titles the first part."""
    if batch_captions and len(batch_captions) != len(batch):
        raise ValueError(f"give one caption per batch picture (got {len(batch_captions)} for {len(batch)})")
    images = [_read(p) for p in pictures]
    rows = [images[r:r + columns] for r in range(0, len(images), columns)]
    top_w = max(sum(im.shape[1] for im in row) + GAP * (len(row) - 1) for row in rows)
    tiles = [_read(p) for p in batch]
    cols = min(len(tiles), max(4, math.ceil(math.sqrt(len(tiles))))) if tiles else 1
    tile_w = max((im.shape[1] for im in tiles), default=1)
    scale = min(1.0, (top_w - GAP * (cols - 1)) / cols / tile_w)
    cell_w = math.floor(tile_w * scale)
    grid_w = cols * cell_w + GAP * (cols - 1)
    head_h = line_height(TITLE_PT + 1)
    cap_h = line_height(TITLE_PT)
    grid_rows = [tiles[r:r + cols] for r in range(0, len(tiles), cols)]
    row_hs = [max(math.floor(im.shape[0] * scale) for im in row) + cap_h for row in grid_rows]
    height = PAD + (head_h if heading else 0) + sum(max(im.shape[0] for im in row) for row in rows) \
        + GAP * (len(rows) - 1) + (2 * GAP + head_h + sum(row_hs) + GAP * (len(row_hs) - 1) if tiles else 0) + PAD
    width = 2 * PAD + max(top_w, grid_w)
    canvas = Canvas(width, height)
    y = PAD
    if heading:
        canvas.text(PAD, y, heading, TITLE_PT + 1, bold=True)
        y += head_h
    for row in rows:
        x = PAD
        for im in row:
            canvas.image(im, x, y)
            x += im.shape[1] + GAP
        y += max(im.shape[0] for im in row) + GAP
    if tiles:
        y += GAP
        canvas.text(PAD, y, f"all {len(tiles)} garments (front and back)", TITLE_PT + 1, bold=True)
        y += head_h
        x0 = PAD + (width - 2 * PAD - grid_w) // 2
        for r, row in enumerate(grid_rows):
            for c, im in enumerate(row):
                k = r * cols + c
                x = x0 + c * (cell_w + GAP)
                caption = f"{k + 1}. {batch_captions[k]}" if batch_captions else f"{k + 1}."
                w, h = math.floor(im.shape[1] * scale), math.floor(im.shape[0] * scale)
                x += (cell_w - w) // 2
                canvas.text(x, y, _fit(caption, TITLE_PT, max(w, cell_w // 2), bold=True), TITLE_PT, bold=True)
                canvas.image(im, x, y + cap_h, w, h)
            y += row_hs[r] + GAP
    return canvas.save(path)

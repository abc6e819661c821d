"""Contact sheet: a PNG grid of garments on the canonical body (headless matplotlib).

    python -m physdrape.garments.contact_sheet --split DIR --out sheet.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from physdrape.garments.canonical import canonical_body
from physdrape.garments.split import load_split

__all__ = ["render_contact_sheet"]


def _draw(ax, body_v, body_f, items, *, view=(15, -60)):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    light = np.array([0.3, 0.5, 0.8])
    light /= np.linalg.norm(light)

    def shaded(v, f, base):
        tri = v[f]
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-20)
        k = 0.35 + 0.65 * np.abs(n @ light)
        return np.clip(np.asarray(base)[None, :] * k[:, None], 0, 1)

    # Matplotlib has no z-buffer: draw every triangle in one collection, sorted far to near.
    # Plot coordinates: (x, z, y) so the body stands up (y-up world).
    tris, cols = [], []
    bv = body_v[:, [0, 2, 1]]
    tris.append(bv[body_f])
    cols.append(shaded(bv, body_f, (0.80, 0.72, 0.65)))
    for v, f, color in items:
        gv = v[:, [0, 2, 1]]
        tris.append(gv[f])
        cols.append(shaded(gv, f, color))
    tris = np.concatenate(tris)
    cols = np.concatenate(cols)
    elev, azim = np.deg2rad(view[0]), np.deg2rad(view[1])
    eye = np.array([np.cos(elev) * np.cos(azim), np.cos(elev) * np.sin(azim), np.sin(elev)])
    depth = tris.mean(1) @ eye
    order = np.argsort(depth)
    pc = Poly3DCollection(tris[order], facecolors=cols[order], edgecolors="none", linewidths=0)
    ax.add_collection3d(pc)
    lo, hi = np.array([-0.35, -0.35, -0.1]), np.array([0.35, 0.35, 0.75])
    ax.set_xlim(lo[0], hi[0]); ax.set_ylim(lo[1], hi[1]); ax.set_zlim(lo[2], hi[2])
    ax.set_box_aspect(hi - lo)
    ax.view_init(elev=view[0], azim=view[1])
    ax.computed_zorder = False
    ax.set_axis_off()


def render_contact_sheet(
    garments,
    out: str | Path,
    *,
    body=None,
    cols: int = 6,
    titles=None,
    view=(10, 60),
    tile_inches: float = 2.6,
    dpi: int = 110,
) -> Path:
    """Render garments (each with .verts (V, 3), .faces (F, 3)) on the canonical body, one tile each.

    Args:
        garments: sequence of garments (y-up metres, canonical body frame).
        out: PNG path to write.
        body: (verts, faces) of the body (default: canonical body, upper half only).
        cols: tiles per row.
        titles: optional label per tile.
        view: (elevation, azimuth) [deg] of the camera.

    Returns:
        the PNG path.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if body is None:
        b = canonical_body()
        body = (b.verts, b.faces)
    bv, bf = body
    # Only the body's upper half matters; drop the rest to keep drawing fast.
    bf = bf[(bv[bf][:, :, 1] > -0.15).all(1)]
    n = len(garments)
    rows = max(1, (n + cols - 1) // cols)
    fig = plt.figure(figsize=(cols * tile_inches, rows * tile_inches * 1.25), dpi=dpi)
    palette = [(0.25, 0.45, 0.80), (0.80, 0.30, 0.30), (0.30, 0.65, 0.40), (0.85, 0.60, 0.20)]
    for i, g in enumerate(garments):
        ax = fig.add_subplot(rows, cols, i + 1, projection="3d")
        _draw(ax, bv, bf, [(np.asarray(g.verts), np.asarray(g.faces), palette[i % len(palette)])],
              view=view)
        if titles is not None:
            ax.set_title(titles[i], fontsize=7)
    fig.subplots_adjust(left=0, right=1, bottom=0, top=0.97, wspace=0, hspace=0.05)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out)
    plt.close(fig)
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--split", required=True, help="directory written by physdrape.garments.split")
    ap.add_argument("--out", default=None, help="PNG path (default: SPLIT/test_contact_sheet.png)")
    ap.add_argument("--subset", default="test", choices=["train", "test"])
    args = ap.parse_args(argv)
    garments = load_split(args.split, args.subset)
    out = args.out or str(Path(args.split) / f"{args.subset}_contact_sheet.png")
    titles = [g.name for g in garments]
    print(render_contact_sheet(garments, out, titles=titles))


if __name__ == "__main__":
    main()

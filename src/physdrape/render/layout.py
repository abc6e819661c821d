"""Pictures laid out in pixels: images placed at exact positions and sizes, text measured before it is
placed, saved at exactly the canvas size (no tight bounding box that would move things)."""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np

__all__ = ["DPI", "Canvas", "line_height", "text_width"]

DPI = 100
_SCRATCH: list = []


def _renderer():
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    if not _SCRATCH:
        fig = Figure(figsize=(1, 1), dpi=DPI)
        FigureCanvasAgg(fig)
        _SCRATCH.append((fig, fig.canvas.get_renderer()))
    return _SCRATCH[0]


def text_width(text: str, size: float, *, bold: bool = False) -> int:
    """Width [px] of one line of `text` at font size `size` [pt]."""
    fig, renderer = _renderer()
    t = fig.text(0, 0, text, fontsize=size, fontweight="bold" if bold else "normal")
    width = t.get_window_extent(renderer).width
    t.remove()
    return int(np.ceil(width))


def line_height(size: float) -> int:
    """Height [px] of a line of text at font size `size` [pt], with spacing."""
    return int(np.ceil(size * DPI / 72 * 1.45))


class Canvas:
    """A white picture of `width` × `height` pixels; positions are (x, y) from the top-left corner."""

    def __init__(self, width: int, height: int):
        from matplotlib.backends.backend_agg import FigureCanvasAgg
        from matplotlib.figure import Figure

        self.width, self.height = int(width), int(height)
        self.fig = Figure(figsize=(self.width / DPI, self.height / DPI), dpi=DPI)
        FigureCanvasAgg(self.fig)

    def rect(self, x: float, y: float, w: float, h: float) -> list[float]:
        """A pixel box as a figure-fraction rectangle (left, bottom, width, height)."""
        return [x / self.width, 1.0 - (y + h) / self.height, w / self.width, h / self.height]

    def image(self, img: np.ndarray, x: float, y: float, w: float | None = None, h: float | None = None):
        """Place `img` (H, W, 3) with its top-left corner at (x, y), scaled to w × h [px] (default: its size)."""
        h = img.shape[0] if h is None else h
        w = img.shape[1] if w is None else w
        ax = self.fig.add_axes(self.rect(x, y, w, h))
        ax.imshow(np.clip(img, 0, 1), interpolation="antialiased", aspect="auto")
        ax.set_axis_off()
        return ax

    def text(self, x: float, y: float, text: str, size: float, *, ha: str = "left", bold: bool = False,
             color=None) -> None:
        """One line of text whose top is at y; x is its left edge, centre or right edge by `ha`."""
        self.fig.text(x / self.width, 1.0 - y / self.height, text, fontsize=size, ha=ha, va="top",
                      fontweight="bold" if bold else "normal", color=color or "black")

    def swatch(self, x: float, y: float, side: float, color) -> None:
        """A filled square of `side` px (a colour key) with its top-left corner at (x, y)."""
        from matplotlib.patches import Rectangle

        left, bottom, w, h = self.rect(x, y, side, side)
        self.fig.add_artist(Rectangle((left, bottom), w, h, transform=self.fig.transFigure, facecolor=color,
                                      edgecolor="0.3", linewidth=0.5))

    def save(self, path: str | os.PathLike) -> Path:
        """Write the picture as a PNG (atomically) and return its path."""
        from physdrape.atomic import write_bytes

        buf = io.BytesIO()
        self.fig.savefig(buf, format="png", dpi=DPI)
        path = Path(path)
        write_bytes(path, buf.getvalue())
        return path

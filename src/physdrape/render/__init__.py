"""Headless pictures of drapes: a small numpy z-buffer rasteriser plus matplotlib for text and layout.

- `render_result`: body + garment from head to feet, front and back side by side; "shaded" (the
  garment in its fabric's colour, `fabric_color`) or "residual" (the per-vertex residual force
  ‖F_int‖/(m g) as a heatmap, faces whose centroid is inside the body in red; the paper's Fig. 1).
- `convergence_figure`: energy and total force over the stretching solver steps (paper Fig. 3).
- `material_sweep_figure`: the same garment and pose in several fabrics side by side (Fig. 6), each
  hem marked and captioned with its drop (`physdrape.render.hem`), the hems' profiles on one chart.
- `compose_gallery`: those PNGs tiled, and for a batch every garment's render in a grid below
  (``physdrape drape --figures`` writes gallery.png; docs/gallery.png is that file from
  ``physdrape drape --pose stand --figures --out /tmp/gallery`` with the bundled model).

No OpenGL, no display: orthographic camera, per-pixel barycentric interpolation of vertex
normals and colours, 2× supersampling.
"""

from __future__ import annotations

from physdrape.render.colors import FABRIC_RGB, fabric_color
from physdrape.render.figures import compose_gallery, convergence_figure, material_sweep_figure, render_result
from physdrape.render.raster import rasterise, render_view

__all__ = [
    "FABRIC_RGB",
    "compose_gallery",
    "convergence_figure",
    "fabric_color",
    "material_sweep_figure",
    "rasterise",
    "render_result",
    "render_view",
]

"""The parts of a multi-piece garment on the canonical body: its pieces, the lower piece's
waistband and the upper pieces' hem.

A MakeHuman suit is one mesh of several connected components (a top and trousers, a jacket over
a shirt). What holds each piece up, and what a user looks at first, are its openings around the
torso: the trousers' waistband and the top's hem. They are found on the template (the canonical
body, rest pose, y-up, the body's axis at x = 0):

- pieces: the connected components of the mesh;
- the **lower piece**: with two or more pieces, the one that reaches lowest (trousers, a skirt);
  a one-piece garment is one when it stays below `LOWER_BODY_TOP` (trousers or a skirt worn
  alone: every top reaches the shoulders);
- **torso openings**: boundary loops whose centre lies within `axis_radius` of the body's vertical
  axis (sleeve cuffs and trouser legs lie off it);
- the **waistband**: the lower piece's highest torso opening;
- the **hem**: the lowest torso opening of the other (upper) pieces.

A one-piece top has no lower piece (waistband None); a garment without a top has no hem.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physdrape.geometry.topology import boundary_loops, connected_components

__all__ = ["LOWER_BODY_TOP", "GarmentParts", "garment_parts", "waistband_band"]

#: Height [m] on the canonical body that a one-piece garment worn on the lower body stays below:
#: above the waist (about 0.05 m), below the armpits (0.39 m); every top reaches the shoulders.
LOWER_BODY_TOP = 0.3


@dataclass(frozen=True)
class GarmentParts:
    """The parts of a garment template (module docstring).

    Attributes:
        piece: connected component of each vertex, shape (V,) int64, numbered 0 … P−1.
        num_pieces: P.
        lower: the lower piece's number, or None (a one-piece top).
        waistband: vertex indices of the lower piece's waistband (K,) int64, or None.
        hem: vertex indices of the upper pieces' hem (K,) int64, or None.
    """

    piece: np.ndarray
    num_pieces: int
    lower: int | None
    waistband: np.ndarray | None
    hem: np.ndarray | None


def garment_parts(verts: np.ndarray, faces: np.ndarray, *, axis_radius: float = 0.06) -> GarmentParts:
    """Pieces, waistband and hem of a template on the canonical body.

    Args:
        verts: template positions [m], shape (V, 3), y-up, the body's axis at x = 0.
        faces: triangles, shape (F, 3) int.
        axis_radius: how far from the body's axis (in x) a torso opening's centre may lie [m].
    """
    x = np.asarray(verts, np.float64)
    f = np.asarray(faces, np.int64)
    piece = connected_components(len(x), f).astype(np.int64)
    num_pieces = int(piece.max()) + 1 if len(piece) else 0
    torso = [loop for loop in boundary_loops(f) if abs(float(x[loop, 0].mean())) < axis_radius]
    lower = None
    if num_pieces >= 2:
        lowest = np.full(num_pieces, np.inf)
        np.minimum.at(lowest, piece, x[:, 1])
        lower = int(np.argmin(lowest))
    elif num_pieces == 1 and float(x[:, 1].max()) < LOWER_BODY_TOP:
        lower = 0
    waistband = hem = None
    if lower is not None:
        own = [loop for loop in torso if piece[loop[0]] == lower]
        if own:
            waistband = max(own, key=lambda loop: float(x[loop, 1].mean()))
    upper = [loop for loop in torso if piece[loop[0]] != lower]
    if upper:
        hem = min(upper, key=lambda loop: float(x[loop, 1].min()))
    return GarmentParts(piece=piece, num_pieces=num_pieces, lower=lower, waistband=waistband, hem=hem)


def waistband_band(verts: np.ndarray, parts: GarmentParts, *, width: float = 0.04) -> np.ndarray:
    """The vertices of the waistband's strip of fabric: those of the lower piece at most `width` [m]
    below the waistband's lowest vertex (template, y-up), (K,) int64 sorted; empty without a
    waistband."""
    if parts.waistband is None:
        return np.zeros(0, np.int64)
    x = np.asarray(verts, np.float64)
    floor = float(x[parts.waistband, 1].min()) - width
    return np.flatnonzero((parts.piece == parts.lower) & (x[:, 1] >= floor)).astype(np.int64)

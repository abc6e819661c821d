"""The hem of a draped top and how far it drops: the measure the material sweep shows and
`bench/material_response.py` tabulates.

Definitions (y up, metres):

- **hem**: the garment's longest opening, i.e. the boundary loop with the largest perimeter at
  X_init (ties: the lower one). For a top this is the waist opening; the neck and the sleeve ends
  are shorter.
- **hem drop** [m]: the mean over the hem's vertices of y_init − y, how far the hem hangs below
  where the skinned garment (X_init, before any physics) put it; positive = lower.
- **hem drop spread** [m]: the standard deviation of that drop over the hem's vertices: near
  zero when the hem moves down as one line, larger when it ripples or tilts.
- **hem azimuth** [deg]: where a hem vertex sits around the body seen from above, measured about
  the hem's centre at X_init: 0 = front (+z, towards the camera of the front view), ±180 = back.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from physdrape.geometry.topology import boundary_loops

__all__ = ["HemDrop", "hem_azimuth", "hem_drop", "hem_loop"]


def hem_loop(faces: np.ndarray, x_init: np.ndarray) -> np.ndarray:
    """The hem's vertex indices in walking order, shape (K,) int64 (module docstring).

    faces: (F, 3) int; x_init: X_init [m], (V, 3). Raises ValueError for a closed mesh.
    """
    loops = boundary_loops(np.asarray(faces, np.int64))
    if not loops:
        raise ValueError("the garment has no opening (no boundary loop), so it has no hem")
    x = np.asarray(x_init, np.float64)
    perimeter = [float(np.linalg.norm(x[loop] - x[np.roll(loop, -1)], axis=1).sum()) for loop in loops]
    longest = max(perimeter)
    ties = [k for k, p in enumerate(perimeter) if p >= longest * (1.0 - 1e-9)]
    return loops[min(ties, key=lambda k: float(x[loops[k], 1].mean()))]


def hem_azimuth(x_init: np.ndarray, hem: np.ndarray) -> np.ndarray:
    """Azimuth of each hem vertex about the hem's centre at X_init [deg], (K,), 0 = front (+z),
    +90 = +x, ±180 = back."""
    p = np.asarray(x_init, np.float64)[hem]
    centre = p.mean(0)
    return np.degrees(np.arctan2(p[:, 0] - centre[0], p[:, 2] - centre[2]))


@dataclass(frozen=True)
class HemDrop:
    """How far a hem dropped (module docstring). drop: per hem vertex y_init − y [m], (K,);
    mean, spread: its mean and standard deviation [m]."""

    drop: np.ndarray
    mean: float
    spread: float


def hem_drop(verts: np.ndarray, x_init: np.ndarray, hem: np.ndarray) -> HemDrop:
    """The drop of the hem vertices `hem` (K,) from X_init (V, 3) to the drape `verts` (V, 3) [m]."""
    drop = np.asarray(x_init, np.float64)[hem, 1] - np.asarray(verts, np.float64)[hem, 1]
    return HemDrop(drop=drop, mean=float(drop.mean()), spread=float(drop.std()))

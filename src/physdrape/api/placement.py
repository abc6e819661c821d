"""Where a user's garment sits before it is draped: its unit, and its place on the canonical body.

Garments are draped in metres, authored on the body model's canonical body (Anny: all phenotypes
0.5, rest A-pose; SMPL: β = 0, zero pose). Files and (verts, faces) pairs in another unit are read
with ``units=`` ("m", "dm", "cm", "mm"; CLI ``--units``) and converted to metres; a garment whose
size says it is in another unit than the one given is refused with the unit to give instead. A
garment that neither touches nor surrounds the canonical body has nothing to hang from: it is
refused unless ``allow_detached=True`` (CLI ``--allow-detached``), which warns instead.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from physdrape.api.types import DrapeError
from physdrape.geometry.mesh import MAX_GARMENT_EXTENT_M
from physdrape.geometry.proximity import BodySurface

#: Metres per unit of each accepted `units`.
UNITS = {"m": 1.0, "dm": 0.1, "cm": 0.01, "mm": 0.001}
UNIT_NAMES = {"m": "metres", "dm": "decimetres", "cm": "centimetres", "mm": "millimetres"}
#: A garment read in dm, cm or mm and narrower than this [m] was read in too small a unit.
MIN_GARMENT_EXTENT = 0.1
#: The width [m] of a typical top or suit: the unit that brings a garment nearest to it is suggested.
TYPICAL_GARMENT_EXTENT = 0.7
#: A garment with a vertex nearer to the canonical body's surface than this [m] (or inside it) touches it.
TOUCH_DISTANCE = 0.05
#: A garment whose vertices leave no angular gap wider than this [deg] around the body's vertical
#: axis (at the garment's own heights) surrounds the body.
SURROUND_MAX_GAP_DEG = 90.0


def unit_scale(units: str) -> float:
    """Metres per unit of `units` ("m", "dm", "cm" or "mm")."""
    if units not in UNITS:
        raise DrapeError(f"units must be one of {', '.join(UNITS)} (the unit of the garment's coordinates; "
                         f"CLI --units), got {units!r}")
    return UNITS[units]


def _best_unit(raw_extent: float) -> str:
    """The unit in which a garment `raw_extent` file units across comes nearest to a typical garment."""
    return min(UNITS, key=lambda u: abs(math.log(max(raw_extent * UNITS[u], 1e-12) / TYPICAL_GARMENT_EXTENT)))


def _advice(unit: str) -> str:
    return f'it looks like {UNIT_NAMES[unit]}: pass units="{unit}" (CLI: --units {unit})'


def check_extent(name: str, verts_m: np.ndarray, units: str) -> None:
    """Refuse a garment whose size [m] (after reading it in `units`) says it is in another unit.

    verts_m: the vertices that faces use, converted to metres, shape (V, 3)."""
    if len(verts_m) == 0:
        return
    extent = float(np.ptp(verts_m, axis=0).max())
    raw = extent / UNITS[units]
    best = _best_unit(raw)
    if extent > MAX_GARMENT_EXTENT_M:
        reading = f"{raw:.4g} units across" + ("" if units == "m" else f" (= {extent:.3g} m read in {units})")
        fix = _advice(best) if best != units else "no unit makes it a garment: check the file"
        raise DrapeError(f"garment {name!r} is {reading}, too large for a garment (at most "
                         f"{MAX_GARMENT_EXTENT_M:g} m); PhysDrape works in metres and {fix}")
    if units != "m" and extent < MIN_GARMENT_EXTENT:
        fix = _advice(best) if best != units else "check the file (or read it in a larger unit)"
        raise DrapeError(f"garment {name!r} is {raw:.4g} units across, only {extent:.3g} m read in {units}, "
                         f"too small for a garment (at least {MIN_GARMENT_EXTENT:g} m); {fix}")


def check_scale(scale: float) -> None:
    """Refuse a fitting `scale` that is really a unit conversion (or is implausible)."""
    if 0.2 <= scale <= 5.0:
        return
    unit = next((u for u, f in UNITS.items() if u != "m" and abs(scale / f - 1.0) < 0.15), None)
    if unit is not None:
        raise DrapeError(f"scale {scale:g} converts {UNIT_NAMES[unit]} to metres: read the garment in its "
                         f'unit with units="{unit}" (CLI: --units {unit}) and keep scale near 1 (it adjusts a '
                         "garment made for a larger or smaller body, e.g. 0.95)")
    raise DrapeError(f"scale {scale:g} is implausible for fitting a garment to the body: give a factor in "
                     '[0.2, 5] (near 1); for a garment in another unit pass units= ("dm", "cm", "mm"; '
                     "CLI: --units)")


def attachment(verts: np.ndarray, body_verts: np.ndarray, surface: BodySurface) -> tuple[float, float]:
    """How a template meets the canonical body: (smallest signed distance of its vertices to the
    body [m] (negative inside), largest angular gap [deg] of its vertices around the body's
    vertical axis at the garment's heights (360 when the body has no vertex at those heights)).

    verts: template vertices [m], (V, 3); body_verts: canonical body vertices [m], (Vb, 3)."""
    d = surface.query(torch.from_numpy(np.asarray(verts, np.float64)).to(surface.verts.dtype)).signed_distance
    nearest = float(d.min())
    lo, hi = float(verts[:, 1].min()), float(verts[:, 1].max())
    band = body_verts[(body_verts[:, 1] >= lo) & (body_verts[:, 1] <= hi)]
    if len(band) == 0:
        return nearest, 360.0
    centre = 0.5 * (band.min(axis=0) + band.max(axis=0))
    angles = np.sort(np.degrees(np.arctan2(verts[:, 2] - centre[2], verts[:, 0] - centre[0])))
    gaps = np.diff(np.concatenate([angles, angles[:1] + 360.0]))
    return nearest, float(gaps.max())


def detached_reason(name: str, nearest: float, gap: float) -> str | None:
    """None when a garment touches or surrounds the body (see `attachment`), else what is wrong."""
    if nearest <= TOUCH_DISTANCE or gap <= SURROUND_MAX_GAP_DEG:
        return None
    return (f"garment {name!r} neither touches nor surrounds the body: its nearest vertex is {nearest:.3g} m from "
            f"the canonical body (touching is within {TOUCH_DISTANCE:g} m) and it goes only {360.0 - gap:.0f} "
            "degrees around it")


def detached_advice(body: str, *, fit_hint: bool) -> str:
    """What to do about a detached garment on a body whose canonical pose is described by `body`."""
    fit = " bring a garment made for another body with `physdrape fit FILE --out fitted.obj`," if fit_hint else ""
    return (f"PhysDrape drapes a garment authored on the canonical body ({body}), in metres (or read with "
            f"units=...), y-up, around or on it: check its position and units,{fit} or pass allow_detached=True "
            "(CLI: --allow-detached) to drape it anyway")

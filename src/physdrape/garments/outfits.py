"""Procedural outfits: a top worn over trousers or shorts, one two-piece template.

An outfit is what the MakeHuman suits are (one mesh whose connected components are the pieces):
the trousers (`garments.trousers`) are made first; the top (`garments.generator`) is then made
with its clearance, wherever it lies over the trousers, at least the trousers' own plus
`LAYER_GAP`, so the top's hem hangs over the waistband. Worn, the lower piece's waistband is
gripped and the pieces keep their layer order (`garments.pieces`, `garments.layering`) as a suit's
do. A crop top leaves the midriff bare: its pieces do not meet.

`generate_valid_outfit` redraws (attempt 1, 2, ...) an outfit whose mesh fails validation (the
pieces must not cross each other or the body) or whose pieces, where they overlap, do not agree
that the top is outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from physdrape.garments.body_fields import body_fields
from physdrape.garments.canonical import CanonicalBody, canonical_body
from physdrape.garments.generator import (
    GarmentCategory,
    GarmentParams,
    GarmentTemplate,
    first_valid_draw,
    generate_garment,
    sample_params,
)
from physdrape.garments.layering import layer_pairs
from physdrape.garments.pieces import garment_parts
from physdrape.garments.trousers import TrousersKind, TrousersParams, generate_trousers, sample_trousers_params

__all__ = ["LAYER_GAP", "OutfitParams", "sample_outfit_params", "generate_outfit", "top_is_outside",
           "generate_valid_outfit"]

#: Least clearance between the top and the trousers it covers [m].
LAYER_GAP = 4e-3
#: How far from the trousers (over the body's surface) the top still keeps the layer gap [m].
_COVER_RADIUS = 0.03


@dataclass(frozen=True)
class OutfitParams:
    """A top and the trousers under it; `seed` the outfit's seed (-1 when set by hand)."""

    top: GarmentParams
    trousers: TrousersParams
    seed: int = -1

    def to_dict(self) -> dict:
        return dict(top=self.top.to_dict(), trousers=self.trousers.to_dict(), seed=self.seed)

    @classmethod
    def from_dict(cls, d: dict) -> OutfitParams:
        return cls(top=GarmentParams.from_dict(d["top"]), trousers=TrousersParams.from_dict(d["trousers"]),
                   seed=int(d["seed"]))


def sample_outfit_params(seed: int, *, attempt: int = 0) -> OutfitParams:
    """Draw an outfit from `seed`: the top's family (T-shirts and long sleeves most often) and the
    trousers' family, then each piece's parameters from seeds of their own."""
    rng = np.random.Generator(np.random.PCG64(np.random.SeedSequence([int(seed), 200, int(attempt)])))
    category = list(GarmentCategory)[int(rng.choice(4, p=[0.35, 0.35, 0.2, 0.1]))]
    kind = list(TrousersKind)[int(rng.choice(3, p=[0.3, 0.2, 0.5]))]
    top_seed, trousers_seed = (int(s) for s in rng.integers(0, 2**31, size=2))
    return OutfitParams(top=sample_params(category, top_seed), trousers=sample_trousers_params(kind, trousers_seed),
                        seed=int(seed))


def _clearance_under(trousers: GarmentTemplate, body: CanonicalBody):
    """The clearance floor (`generate_garment`'s `clearance_floor`) of a top worn over `trousers`:
    at body points within `_COVER_RADIUS` of where the trousers lie, their clearance + LAYER_GAP."""
    d, c, _ = body_fields(body).query(trousers.verts)
    tree = cKDTree(c)

    def floor(points: np.ndarray) -> np.ndarray:
        near = cKDTree(points).sparse_distance_matrix(tree, _COVER_RADIUS, output_type="coo_matrix")
        top = np.full(len(points), -np.inf)
        np.maximum.at(top, near.row, d[near.col])
        return np.where(np.isfinite(top), top + LAYER_GAP, 0.0)

    return floor


def generate_outfit(params: OutfitParams, *, target_edge: float = 0.015,
                    body: CanonicalBody | None = None) -> GarmentTemplate:
    """The outfit's template: the trousers' vertices first, then the top's (faces likewise)."""
    body = canonical_body() if body is None else body
    trousers = generate_trousers(params.trousers, target_edge=target_edge, body=body)
    top = generate_garment(params.top, target_edge=target_edge, body=body,
                           clearance_floor=_clearance_under(trousers, body))
    verts = np.concatenate([trousers.verts, top.verts])
    faces = np.concatenate([trousers.faces, top.faces + trousers.num_verts])
    return GarmentTemplate(verts=verts, faces=faces, params=params, name=f"outfit_{params.seed}")


def top_is_outside(outfit: GarmentTemplate, body: CanonicalBody) -> bool:
    """Whether the outfit's pieces, where they overlap, agree that the top lies over the trousers
    (always true when they do not overlap)."""
    parts = garment_parts(outfit.verts, outfit.faces)
    if parts.num_pieces != 2 or parts.lower is None:
        return False
    lp = layer_pairs(outfit.verts, parts.piece, body.verts, body.faces)
    if len(lp.pairs) == 0:
        return True
    top = 1 - parts.lower
    return bool(lp.over[top, parts.lower]) and not bool(lp.over[parts.lower, top])


def generate_valid_outfit(seed: int, *, target_edge: float = 0.015, max_attempts: int = 12,
                          body: CanonicalBody | None = None) -> tuple[GarmentTemplate, int]:
    """The first draw (attempt 0, 1, ...) of `seed` whose outfit passes validation and keeps its top
    outside. Returns (outfit, attempt); raises `GarmentError` after `max_attempts` failures."""
    body = canonical_body() if body is None else body
    return first_valid_draw(
        lambda attempt: generate_outfit(sample_outfit_params(seed, attempt=attempt), target_edge=target_edge,
                                        body=body),
        body=body, max_attempts=max_attempts, what=f"outfit for seed {seed}",
        accept=lambda outfit: top_is_outside(outfit, body))

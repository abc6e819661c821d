"""Procedural trousers and shorts authored on the canonical body in its rest pose.

The recipe of the tops (`garments.generator`) for the lower body:

1. A coverage field on the body surface: below the waistline (`waist_height`, dipping at the
   front by `waist_dip`) and, on the legs, up to `leg_length` along the hip→ankle axis
   (leg-ness = the smoothed skinning label, `body_fields.LegFields`); the arms and hands that
   hang beside the hips are never covered.
2. The surface is clipped along the field's zero level set on a low-pass copy of the body that
   fills the seat's cleft and the crotch but leaves the leg tubes round; the largest piece is kept.
3. Isotropic remeshing, then the shrink-wrap to the offset (margin + looseness at the hips,
   `leg_looseness` on the legs, growing by `flare` toward the leg openings, never more than 0.4 of
   the free space in front of the body: the thighs' inner sides face each other) and the local
   untangling.

A pair of trousers is one piece with three openings (the waistband and two legs); worn with a top
it is the lower piece of an outfit (`garments.outfits`), its waistband gripped
(`physics.grip`). Positions y-up, metres, body facing +z.
"""

from __future__ import annotations

import enum
from dataclasses import asdict, dataclass

import numpy as np

from physdrape.garments.body_fields import BodyFields, LegFields, body_fields, leg_fields
from physdrape.garments.canonical import CanonicalBody, canonical_body
from physdrape.garments.clipping import clip_mesh
from physdrape.garments.generator import COLLISION_MARGIN, GarmentTemplate, first_valid_draw
from physdrape.garments.remesh import remesh
from physdrape.garments.shrink_wrap import body_vertex_under, wrap_patch

__all__ = ["TrousersKind", "TrousersParams", "sample_trousers_params", "trousers_coverage", "generate_trousers",
           "generate_valid_trousers"]


class TrousersKind(str, enum.Enum):
    """The lower-body families, by leg length."""

    SHORTS = "shorts"
    CAPRI = "capri"
    TROUSERS = "trousers"


@dataclass(frozen=True)
class TrousersParams:
    """Parameters of one pair of procedural trousers (lengths in metres, canonical body frame).

    Attributes:
        kind: the family (by leg length).
        leg_length: where the legs end, measured from the hip joint along the hip→ankle axis [m]
            (the ankle joint is about 0.79 m down it).
        waist_height: height of the waistline at the back and sides [m] (y; the navel is near 0.1).
        waist_dip: how far the waistline dips at the front [m].
        looseness: clearance of the hips and seat beyond the collision margin [m].
        leg_looseness: clearance of the legs beyond the collision margin [m].
        flare: extra clearance reached at the leg openings, growing from the hip down [m].
        seed: the seed the parameters were drawn with (-1 when set by hand).
    """

    kind: TrousersKind
    leg_length: float
    waist_height: float
    waist_dip: float
    looseness: float
    leg_looseness: float
    flare: float
    seed: int = -1

    def to_dict(self) -> dict:
        d = asdict(self)
        d["kind"] = self.kind.value
        return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict) -> TrousersParams:
        d = dict(d)
        d["kind"] = TrousersKind(d["kind"])
        return cls(**d)


#: Leg length ranges per family [m] along the hip→ankle axis.
_LEG_LENGTHS = {TrousersKind.SHORTS: (0.16, 0.30), TrousersKind.CAPRI: (0.46, 0.60),
                TrousersKind.TROUSERS: (0.70, 0.76)}


def sample_trousers_params(kind: TrousersKind | str, seed: int, *, attempt: int = 0) -> TrousersParams:
    """Draw the parameters of one pair of `kind` from `seed` (numpy PCG64); `attempt` > 0 gives the
    redraws `generate_valid_trousers` uses when a draw fails validation."""
    kind = TrousersKind(kind)
    ss = np.random.SeedSequence([int(seed), 100 + list(TrousersKind).index(kind), int(attempt)])
    rng = np.random.Generator(np.random.PCG64(ss))
    u = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    return TrousersParams(
        kind=kind, leg_length=u(*_LEG_LENGTHS[kind]), waist_height=u(0.04, 0.12), waist_dip=u(0.0, 0.04),
        looseness=u(0.003, 0.02), leg_looseness=u(0.004, 0.03), flare=u(0.0, 0.03), seed=int(seed),
    )


def trousers_coverage(p: TrousersParams, f: BodyFields, lf: LegFields, x: np.ndarray) -> np.ndarray:
    """Signed coverage of points `x` (body vertices) [m-ish]: ≥ 0 where the trousers cover."""
    front = np.clip((x[:, 2] - 0.02) / 0.1, 0.0, 1.0)
    phi_waist = p.waist_height - p.waist_dip * front - x[:, 1]
    t_eff = lf.leg * lf.t + (1.0 - lf.leg) * (-0.1)  # the torso counts as above the hip
    phi_leg = p.leg_length - t_eff
    phi_arm = (0.3 - f.arm) * 0.1
    return np.minimum(np.minimum(phi_waist, phi_leg), phi_arm)


def generate_trousers(
    params: TrousersParams,
    *,
    target_edge: float = 0.015,
    body: CanonicalBody | None = None,
    wrap_iterations: int = 40,
) -> GarmentTemplate:
    """Build the template mesh of one pair of procedural trousers on the canonical body.

    Args:
        params: the parameters (see `sample_trousers_params`).
        target_edge: edge length of the output mesh [m].
        body: the canonical body (default: Anny, phenotypes 0.5, rest pose).
        wrap_iterations: smoothing/push-out sweeps of the shrink-wrap.

    Returns:
        the garment (`params` a `TrousersParams`); deterministic for given params and body.
    """
    body = canonical_body() if body is None else body
    f, lf = body_fields(body), leg_fields(body)
    v, fa = clip_mesh(lf.smooth_verts, body.faces, trousers_coverage(params, f, lf, body.verts))
    v, fa = remesh(v, fa, target_edge=0.92 * target_edge)  # the offset stretches the sheet a little
    nn = body_vertex_under(v, f, body)
    leg = np.clip(lf.leg[nn], 0.0, 1.0)
    down = np.clip(lf.t[nn] / params.leg_length, 0.0, 1.0)
    offset = (COLLISION_MARGIN + 1e-3 + (1 - leg) * params.looseness
              + leg * (params.leg_looseness + params.flare * down**2))
    # Half-strength smoothing everywhere: enough to bridge the seat and the crotch, little enough
    # that the leg tubes keep their girth.
    v = wrap_patch(v, fa, offset, lf, body, iterations=wrap_iterations, margin=COLLISION_MARGIN,
                   smooth_weight=np.full(len(v), 0.5))
    return GarmentTemplate(verts=v, faces=fa, params=params, name=f"{params.kind.value}_{params.seed}")


def generate_valid_trousers(
    kind: TrousersKind | str,
    seed: int,
    *,
    target_edge: float = 0.015,
    max_attempts: int = 12,
    body: CanonicalBody | None = None,
) -> tuple[GarmentTemplate, int]:
    """The first parameter draw (attempt 0, 1, ...) of `seed` whose trousers pass validation.

    Returns:
        (garment, attempt). Raises `GarmentError` after `max_attempts` failures.
    """
    body = canonical_body() if body is None else body
    return first_valid_draw(
        lambda attempt: generate_trousers(sample_trousers_params(kind, seed, attempt=attempt), target_edge=target_edge,
                                          body=body),
        body=body, max_attempts=max_attempts, what=f"{TrousersKind(kind).value} for seed {seed}")

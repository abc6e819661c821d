"""Procedural upper-body garments authored on the canonical body in its rest pose.

Recipe (per garment, deterministic for its parameters):

1. A scalar coverage field on the body surface says what the garment covers: torso between the
   hem and the neckline (an elliptic cylinder around the neck, dipping at the front), the arms
   up to the sleeve length measured along the shoulder→wrist axis (arm-ness = the smoothed
   skinning label, so the cut does not follow the jagged bone border), or an armhole
   (ellipsoid under the shoulder) for sleeveless tops. Sleeved garments also get small holes
   at the armpit hollows (and inner elbows for long sleeves).
2. The surface is clipped along the field's zero level set - on a lightly smoothed copy of the
   body (torso smoothed, arms kept: smoothing folds a bent tube) so clefts and creases are
   filled - the largest piece is kept and the crease holes are filled with fans: webs that
   bridge the armpit instead of following it.
3. Isotropic remeshing to the target edge length (boundary loops kept as feature lines).
4. Shrink-wrap to the offset (margin + looseness, flare toward the hem, width at the sides,
   never more than 0.4 of the free space in front of the body): Laplacian smoothing (torso
   strongly, sleeves weakly) alternating with neighbour-averaged push-outs, first against the
   smoothed body, then the real one, then tangential relaxation.
5. Local untangling of any remaining self-intersection; every vertex ends ≥ the collision
   margin off the body. `generate_valid_garment` validates and redraws the rare failures.

What the recipe reads off the body is in `body_fields`, the cut (step 2) in `clipping`, steps 4-5
in `shrink_wrap`; this module holds the parameters, the coverage field and the entry points.

Positions y-up, metres, body facing +z.
"""

from __future__ import annotations

import enum
from dataclasses import asdict, dataclass, field

import numpy as np

from physdrape.garments.body_fields import BodyFields, body_fields
from physdrape.garments.canonical import CanonicalBody, canonical_body
from physdrape.garments.clipping import clip_mesh, fill_crease_holes
from physdrape.garments.remesh import remesh
from physdrape.garments.shrink_wrap import body_vertex_under, wrap_patch
from physdrape.garments.validate import GarmentError, validate_garment

__all__ = [
    "GarmentCategory",
    "GarmentParams",
    "GarmentTemplate",
    "sample_params",
    "generate_garment",
    "generate_batch",
    "generate_valid_garment",
    "COLLISION_MARGIN",
]

#: Minimum clearance between a generated garment and the canonical body [m] (DESIGN: ε = 2 mm).
COLLISION_MARGIN = 2e-3

#: Radius of the hole cut at each armpit hollow and refilled by a web [m].
_PIT_RADIUS = 0.06
#: Radius of the hole cut at each inner elbow (long sleeves) and refilled by a web [m].
_ELBOW_RADIUS = 0.035


class GarmentCategory(str, enum.Enum):
    """The procedural garment families."""

    TSHIRT = "tshirt"
    LONGSLEEVE = "longsleeve"
    TANKTOP = "tanktop"
    CROPTOP = "croptop"


@dataclass(frozen=True)
class GarmentParams:
    """Parameters of one procedural garment (lengths in metres, canonical body frame).

    Attributes:
        category: garment family.
        sleeve_length: sleeve end measured from the shoulder joint along the arm [m];
            0 = sleeveless (then `armhole_depth` shapes the armhole).
        hem_height: height of the hem [m] in the body frame (y; the navel is near 0.1).
        neck_width: half-width of the neck opening [m].
        neck_depth: how far the neckline dips at the front below the neck base [m].
        looseness: clearance of the torso part beyond the collision margin [m].
        sleeve_looseness: clearance of the sleeves beyond the collision margin [m].
        flare: extra clearance reached at the hem, growing from the chest down [m].
        width: extra clearance at the sides of the torso (scaled by the lateral normal) [m].
        armhole_depth: for sleeveless tops, how far the armhole reaches below the shoulder [m].
        seed: the seed the parameters were drawn with (-1 when set by hand).
    """

    category: GarmentCategory
    sleeve_length: float
    hem_height: float
    neck_width: float
    neck_depth: float
    looseness: float
    sleeve_looseness: float
    flare: float
    width: float
    armhole_depth: float = 0.0
    seed: int = -1

    def to_dict(self) -> dict:
        d = asdict(self)
        d["category"] = self.category.value
        return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict) -> "GarmentParams":
        d = dict(d)
        d["category"] = GarmentCategory(d["category"])
        return cls(**d)


@dataclass
class GarmentTemplate:
    """A garment template: the rest mesh on the canonical body (numpy, as authored or loaded).

    `physdrape.geometry.garment.Garment.from_mesh(t.verts, t.faces, name=t.name)` turns it into
    the rest state the physics and the network read.

    Attributes:
        verts: rest positions [m], shape (V, 3) float64, y-up.
        faces: triangles, shape (F, 3) int64, oriented outward.
        params: the generator parameters (`GarmentParams`, `garments.trousers.TrousersParams` or
            `garments.outfits.OutfitParams`; None for loaded garments).
        name: a label.
    """

    verts: np.ndarray
    faces: np.ndarray
    params: object | None = None
    name: str = "garment"
    meta: dict = field(default_factory=dict)

    @property
    def num_verts(self) -> int:
        return int(len(self.verts))

    @property
    def num_faces(self) -> int:
        return int(len(self.faces))


def sample_params(category: GarmentCategory | str, seed: int, *, attempt: int = 0) -> GarmentParams:
    """Draw the parameters of one garment of `category` from `seed` (numpy PCG64); `attempt`
    > 0 gives the redraws `generate_valid_garment` uses when a draw fails validation."""
    category = GarmentCategory(category)
    ss = np.random.SeedSequence([int(seed), list(GarmentCategory).index(category), int(attempt)])
    rng = np.random.Generator(np.random.PCG64(ss))
    u = lambda lo, hi: float(rng.uniform(lo, hi))  # noqa: E731
    neck_width = u(0.075, 0.10)
    neck_depth = u(0.01, 0.08)
    looseness = u(0.004, 0.035)
    sleeve_looseness = u(0.004, 0.025)
    flare = u(0.0, 0.03)
    width = u(0.0, 0.02)
    armhole_depth = 0.0
    if category is GarmentCategory.TSHIRT:
        sleeve, hem = u(0.16, 0.26), u(-0.04, 0.05)
    elif category is GarmentCategory.LONGSLEEVE:
        sleeve, hem = u(0.34, 0.40), u(-0.04, 0.05)
    elif category is GarmentCategory.TANKTOP:
        sleeve, hem = 0.0, u(-0.04, 0.05)
        neck_width, neck_depth = u(0.08, 0.10), u(0.04, 0.12)
        armhole_depth = u(0.12, 0.17)
    else:  # crop top: short sleeves or none, hem above the navel
        sleeve = u(0.16, 0.22) if rng.uniform() < 0.6 else 0.0
        hem = u(0.15, 0.24)
        armhole_depth = u(0.12, 0.16) if sleeve == 0.0 else 0.0
        flare = u(0.0, 0.01)
    return GarmentParams(
        category=category, sleeve_length=sleeve, hem_height=hem, neck_width=neck_width,
        neck_depth=neck_depth, looseness=looseness, sleeve_looseness=sleeve_looseness,
        flare=flare, width=width, armhole_depth=armhole_depth, seed=int(seed),
    )


def coverage_field(p: GarmentParams, f: BodyFields, x: np.ndarray) -> np.ndarray:
    """Signed coverage of points `x` (body vertices) [m-ish]: ≥ 0 where the garment covers."""
    arm, s = f.arm, f.s
    y = x[:, 1]
    # Hem: the torso part ends at hem_height; the arms are lifted out of the hem's reach.
    phi_hem = y - p.hem_height + 0.5 * np.clip(arm, 0.0, 1.0)
    # Neckline: outside an elliptic cylinder around the neck, or below its (front-dipping) base.
    c = f.neck_center
    dz = x[:, 2] - (c[2] + 0.01)
    rho = np.sqrt((x[:, 0] / p.neck_width) ** 2 + (dz / (p.neck_width * 0.95)) ** 2)
    front = np.clip(dz / p.neck_width, 0.0, 1.0)
    y0 = f.neck_base - p.neck_depth * front**1.5
    phi_neck = np.maximum((rho - 1.0) * p.neck_width, y0 - y)
    phi_neck = np.minimum(phi_neck, c[1] + 0.03 - y)  # never the head
    if p.sleeve_length > 0:
        # Sleeve: cut across the arm at sleeve_length (measured only where the body is arm).
        s_eff = arm * s + (1.0 - arm) * (-0.1)
        phi_arm = p.sleeve_length - s_eff
        for centre, radius in _crease_holes(p, f):
            phi_arm = np.minimum(phi_arm, np.linalg.norm(x - centre, axis=1) - radius)
    else:
        # Armhole: keep where arm-ness is low and outside an ellipsoid hanging from the shoulder.
        phi_arm = np.full(len(x), np.inf)
        for sgn, a in f.shoulders.items():
            ctr = np.array([a[0] + sgn * 0.01, a[1] - 0.5 * p.armhole_depth + 0.03, a[2]])
            r = np.array([0.07, 0.5 * p.armhole_depth + 0.04, 0.11])
            q = np.sqrt((((x - ctr) / r) ** 2).sum(1)) - 1.0
            phi_arm = np.where(f.side == sgn, q * 0.06, phi_arm)
        phi_arm = np.minimum(phi_arm, (0.25 - arm) * 0.1)
    return np.minimum(np.minimum(phi_hem, phi_neck), phi_arm)


def _crease_holes(p: GarmentParams, f: BodyFields) -> list:
    """(centre, radius) of the holes cut at body creases and refilled by webs."""
    if p.sleeve_length <= 0:
        return []
    holes = [(pit, _PIT_RADIUS) for pit in f.pits.values()]
    for pt, s_el in f.elbows.values():
        if p.sleeve_length > s_el + _ELBOW_RADIUS + 0.03:
            holes.append((pt, _ELBOW_RADIUS))
    return holes


def generate_garment(
    params: GarmentParams,
    *,
    target_edge: float = 0.015,
    body: CanonicalBody | None = None,
    wrap_iterations: int = 40,
    clearance_floor=None,
) -> GarmentTemplate:
    """Build the template mesh of one procedural garment on the canonical body.

    Args:
        params: garment parameters (see `sample_params`).
        target_edge: edge length of the output mesh [m].
        body: the canonical body (default: Anny, phenotypes 0.5, rest pose).
        wrap_iterations: smoothing/push-out sweeps of the shrink-wrap.
        clearance_floor: None, or a function of the body points under the garment's vertices
            [m] (N, 3) giving the least clearance each vertex must keep [m] (N,) (0: none): the
            room a garment worn underneath takes (`garments.outfits`).

    Returns:
        the garment; deterministic for given params and body.
    """
    body = canonical_body() if body is None else body
    f = body_fields(body)
    phi = coverage_field(params, f, body.verts)
    v, fa = clip_mesh(f.smooth_verts, body.faces, phi)
    holes = _crease_holes(params, f)
    if holes:
        v, fa = fill_crease_holes(v, fa, holes)
    # The offset stretches the sheet by a few per cent: aim the remesher a little short.
    v, fa = remesh(v, fa, target_edge=0.92 * target_edge)
    # Offsets per garment vertex from the nearest body vertex's arm-ness and height.
    nn = body_vertex_under(v, f, body)
    arm = np.clip(f.arm[nn], 0.0, 1.0)
    chest_y = float(f.shoulders[1.0][1]) - 0.1
    ramp = np.clip((chest_y - v[:, 1]) / max(chest_y - params.hem_height, 1e-3), 0.0, 1.0)
    lateral = np.abs(f.normals[nn, 0])
    offset = (
        COLLISION_MARGIN + 1e-3
        + (1 - arm) * (params.looseness + params.flare * ramp**2 + params.width * lateral**2)
        + arm * params.sleeve_looseness
    )
    # Smoothing strong on the torso (bridges the armpit), weak on the sleeves (it would only shrink
    # and pleat their tubes); the sleeves are nearly final once offset along their normals.
    weight = np.clip(1.0 - arm, 0.0, 1.0) ** 2 * 0.9 + 0.1
    v = wrap_patch(v, fa, offset, f, body, iterations=wrap_iterations, margin=COLLISION_MARGIN, smooth_weight=weight,
                   clearance_floor=clearance_floor)
    return GarmentTemplate(verts=v, faces=fa, params=params, name=f"{params.category.value}_{params.seed}")


def generate_valid_garment(
    category: GarmentCategory | str,
    seed: int,
    *,
    target_edge: float = 0.015,
    max_attempts: int = 12,
    body: CanonicalBody | None = None,
) -> tuple[GarmentTemplate, int]:
    """The first parameter draw (attempt 0, 1, ...) of `seed` whose garment passes validation.

    Returns:
        (garment, attempt). Raises `GarmentError` after `max_attempts` failures.
    """
    body = canonical_body() if body is None else body
    return first_valid_draw(
        lambda attempt: generate_garment(sample_params(category, seed, attempt=attempt), target_edge=target_edge,
                                         body=body),
        body=body, max_attempts=max_attempts, what=f"garment for {category} seed {seed}")


def first_valid_draw(make, *, body: CanonicalBody, max_attempts: int, what: str,
                     accept=None) -> tuple[GarmentTemplate, int]:
    """The first of `make(attempt)` for attempt 0, 1, ... whose garment passes validation on `body`
    (and `accept(garment)` when given), with its attempt recorded in its meta.

    Returns:
        (garment, attempt). Raises `GarmentError` naming `what` after `max_attempts` failures.
    """
    report = None
    for attempt in range(max_attempts):
        g = make(attempt)
        report = validate_garment(g.verts, g.faces, name=g.name, body=(body.verts, body.faces),
                                  margin=COLLISION_MARGIN)
        if report.ok and (accept is None or accept(g)):
            g.meta["attempt"] = attempt
            return g, attempt
    raise GarmentError(f"no valid {what} in {max_attempts} draws; last:\n{report}")


def generate_batch(
    seed: int, count: int, *, target_edge: float = 0.015, categories=None
) -> list[GarmentTemplate]:
    """`count` valid garments cycling through `categories` (default all), seeds from `seed`."""
    cats = list(GarmentCategory) if categories is None else [GarmentCategory(c) for c in categories]
    out = []
    for i in range(count):
        g, _ = generate_valid_garment(cats[i % len(cats)], seed * 100_003 + i, target_edge=target_edge)
        out.append(g)
    return out

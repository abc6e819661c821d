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

Positions y-up, metres, body facing +z.
"""

from __future__ import annotations

import enum
from dataclasses import asdict, dataclass, field

import numpy as np
import scipy.sparse as sp

from physdrape.garments.canonical import CanonicalBody, canonical_body
from physdrape.garments.intersections import ray_hit_distances, self_intersecting_faces
from physdrape.garments.numpy_geometry import BodyDistance, vertex_normals
from physdrape.garments.remesh import remesh
from physdrape.garments.validate import GarmentError, validate_garment
from physdrape.geometry.mesh import face_areas
from physdrape.geometry.topology import (
    boundary_edges,
    boundary_loops,
    connected_components,
    drop_unused_vertices,
    undirected_edges,
    vertex_adjacency,
)

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

_DEBUG = False
#: Height of the armpit hollow below the shoulder joint the parameters are designed for [m].
_PIT_BELOW_SHOULDER = 0.128
#: Radius of the hole cut at each armpit hollow and refilled by a web [m].
_PIT_RADIUS = 0.06
#: Radius of the hole cut at each inner elbow (long sleeves) and refilled by a web [m].
_ELBOW_RADIUS = 0.035
_ARM_PREFIXES = ("upperarm", "lowerarm", "wrist", "finger", "metacarpal")


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
        params: the generator parameters (None for loaded garments).
        name: a label.
    """

    verts: np.ndarray
    faces: np.ndarray
    params: GarmentParams | None = None
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


# ----------------------------------------------------------------------------- body fields
class _BodyFields:
    """Per-body-vertex quantities the coverage field is built from (computed once per body)."""

    def __init__(self, body: CanonicalBody):
        self.body = body
        v = body.verts
        labels = np.array(body.bone_labels)
        is_arm_bone = np.array([lab.startswith(_ARM_PREFIXES) for lab in labels])
        dom_arm = is_arm_bone[body.vertex_bone].astype(np.float64)
        # Smooth the 0/1 arm label over the surface: a soft arm-ness whose 0.5 level is smooth.
        e = undirected_edges(body.faces)
        adj = vertex_adjacency(len(v), e)
        deg = np.asarray(adj.sum(1)).ravel()
        walk = sp.diags(1.0 / deg) @ adj
        w = dom_arm
        for _ in range(12):
            w = 0.5 * w + 0.5 * (walk @ w)
        self.arm = w
        self.side = np.sign(v[:, 0])
        # Armpit hollows: the lowest point of the arm/torso border on each side (from the
        # surface alone). Sleeved garments cut a small hole there and fill it with a web.
        border = np.abs(w - 0.5) < 0.2
        self.pits = {}
        for sgn in (1.0, -1.0):
            m = border & (self.side == sgn) & (v[:, 1] > 0.2)
            self.pits[sgn] = v[m][np.argmin(v[m, 1])].copy()
        # Landmarks (shoulder, elbow, wrist, neck) come from the rig's joint heads, moved
        # vertically so the armpit sits where the garment parameters were designed for (12.8 cm
        # below the shoulder joint): the cuts then follow the surface, whatever the rig's
        # convention for its joint heads.
        dy = float(self.pits[1.0][1] - body.joints["upperarm01.L"][1]) + _PIT_BELOW_SHOULDER
        joints = {k: j + np.array([0.0, dy, 0.0]) for k, j in body.joints.items()}
        self.landmark_shift = dy
        # Arm coordinate s: distance along the shoulder→wrist axis of the vertex's side [m].
        s = np.zeros(len(v))
        for sfx, sgn in ((".L", 1.0), (".R", -1.0)):
            a = joints["upperarm01" + sfx]
            d = joints["wrist" + sfx] - a
            d = d / np.linalg.norm(d)
            m = self.side == sgn
            s[m] = (v[m] - a) @ d
        self.s = s
        self.normals = vertex_normals(v, body.faces)
        # A low-pass copy of the surface (plain Laplacian: it shrinks a little but never folds,
        # unlike Taubin) the garment patch is cut from: clefts and creases (gluteal cleft,
        # clavicle pits) are filled, so the cut loops and the offset sheet do not dive in.
        # Only the torso is smoothed at full strength: Laplacian smoothing folds a bent tube at
        # its inner side (the elbow), so the arms are barely touched.
        xs = v.copy()
        keep_arm = (0.5 * np.clip(1.0 - w, 0.0, 1.0) ** 2)[:, None]
        for _ in range(20):
            xs = xs + keep_arm * (walk @ xs - xs)
        self.smooth_verts = xs
        self.smooth_query = BodyDistance(xs, body.faces)
        self.neck_center = joints["neck01"].copy()
        self.neck_base = float(joints["neck01"][1]) - 0.035
        self.shoulders = {sgn: joints["upperarm01" + sfx] for sfx, sgn in ((".L", 1.0), (".R", -1.0))}
        self.query = BodyDistance(body.verts, body.faces)
        self.edges = e
        # Inner-elbow creases: the surface point on the concave side of the elbow bend, and its
        # arm coordinate s (long sleeves cut and web it like the armpit).
        self.elbows = {}
        for sfx, sgn in ((".L", 1.0), (".R", -1.0)):
            sh, el, wr = (joints[k + sfx] for k in ("upperarm01", "lowerarm01", "wrist"))
            u = (el - sh) / np.linalg.norm(el - sh)
            t = (wr - el) / np.linalg.norm(wr - el)
            concave = (t - u) / np.linalg.norm(t - u)
            r = v - el
            along = r @ concave
            perp = np.linalg.norm(r - along[:, None] * concave, axis=1)
            m = (self.side == sgn) & (np.linalg.norm(r, axis=1) < 0.08) & (along > 0) & (w > 0.9)
            k = np.flatnonzero(m)[np.argmin(perp[m])]  # where the concave-side ray leaves the arm
            self.elbows[sgn] = (v[k].copy(), float(s[k]))


_FIELDS: dict[int, _BodyFields] = {}


def _fields(body: CanonicalBody) -> _BodyFields:
    key = id(body)
    if key not in _FIELDS:
        _FIELDS[key] = _BodyFields(body)
    return _FIELDS[key]


def coverage_field(p: GarmentParams, f: _BodyFields, x: np.ndarray) -> np.ndarray:
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


def clip_mesh(verts: np.ndarray, faces: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The part of a triangle mesh where the per-vertex field `phi` ≥ 0, cut along phi = 0.

    New vertices sit where the edges cross zero (linear interpolation); cut triangles become
    one or two triangles with the input's orientation. Returns (verts, faces) with unused
    vertices dropped.
    """
    phi = np.where(phi == 0.0, 1e-12, phi)
    pos = phi > 0
    npos = pos[faces].sum(1)
    keep = faces[npos == 3]
    cut = faces[(npos == 1) | (npos == 2)]
    # Rotate each cut triangle so its odd-one-out vertex comes first (keeps the orientation).
    p = pos[cut]
    odd = np.where(p.sum(1) == 1, np.argmax(p, 1), np.argmin(p, 1))
    rot = np.stack([cut[np.arange(len(cut)), (odd + k) % 3] for k in range(3)], 1)
    a, b, c = rot[:, 0], rot[:, 1], rot[:, 2]
    # Crossing points on edges ab and ac.
    pairs = np.concatenate([np.stack([a, b], 1), np.stack([a, c], 1)])
    key = np.sort(pairs, 1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    t = phi[uniq[:, 0]] / (phi[uniq[:, 0]] - phi[uniq[:, 1]])
    new_v = verts[uniq[:, 0]] + t[:, None] * (verts[uniq[:, 1]] - verts[uniq[:, 0]])
    nv = len(verts)
    ab = nv + inv[: len(cut)]
    ac = nv + inv[len(cut):]
    single = pos[a]  # the odd vertex is the only one inside: one triangle
    tri1 = np.stack([a, ab, ac], 1)[single]
    two = ~single  # a outside, b and c inside: quad (ab, b, c, ac)
    tri2 = np.stack([ab[two], b[two], c[two]], 1)
    tri3 = np.stack([ab[two], c[two], ac[two]], 1)
    all_v = np.concatenate([verts, new_v])
    all_f = np.concatenate([keep, tri1, tri2, tri3]).astype(np.int64)
    return _largest_component(all_v, all_f)


def _largest_component(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The face-connected component with the largest area, unused vertices dropped."""
    face_label = connected_components(len(verts), faces)[faces[:, 0]]
    keep = face_label == np.bincount(face_label, weights=face_areas(verts, faces)).argmax()
    return drop_unused_vertices(verts, faces[keep])


def _crease_holes(p: GarmentParams, f: _BodyFields) -> list:
    """(centre, radius) of the holes cut at body creases and refilled by webs."""
    if p.sleeve_length <= 0:
        return []
    holes = [(pit, _PIT_RADIUS) for pit in f.pits.values()]
    for pt, s_el in f.elbows.values():
        if p.sleeve_length > s_el + _ELBOW_RADIUS + 0.03:
            holes.append((pt, _ELBOW_RADIUS))
    return holes


def _fill_pits(verts: np.ndarray, faces: np.ndarray, f: _BodyFields, holes: list):
    """Fill the armpit holes with a fan around the loop's centroid (the remesher refines it and
    the shrink-wrap turns it into a web bridging the armpit crease)."""
    loops = boundary_loops(faces)
    directed = {(int(a), int(b)) for a, b in np.concatenate(
        [faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])}
    new_v, new_f = [verts], [faces]
    nv = len(verts)
    for pit, radius in holes:
        if not loops:
            break
        k = int(np.argmin([np.linalg.norm(verts[l].mean(0) - pit) for l in loops]))
        if np.linalg.norm(verts[loops[k]].mean(0) - pit) > 1.5 * radius:
            continue
        loop = loops.pop(k)
        a, b = int(loop[0]), int(loop[1])
        if (a, b) in directed:  # the faces use a→b, so the fill must run b→a
            loop = loop[::-1]
        new_v.append(verts[loop].mean(0, keepdims=True))
        nxt = np.roll(loop, -1)
        new_f.append(np.stack([loop, nxt, np.full(len(loop), nv)], 1))
        nv += 1
    return np.concatenate(new_v), np.concatenate(new_f).astype(np.int64)


def _smoother(faces: np.ndarray, nv: int):
    """One smoothing sweep: Laplacian on interior vertices (bridges concavities), Taubin λ|μ
    along boundary loops (smooths the loop without shrinking it). Returns (sweep, adjacency)."""
    e = undirected_edges(faces)
    be = boundary_edges(faces)
    on_b = np.zeros(nv, bool)
    on_b[be.ravel()] = True

    def walk_of(edges, rows):
        w = vertex_adjacency(nv, edges)
        walk = sp.diags(1.0 / np.maximum(np.asarray(w.sum(1)).ravel(), 1)) @ w
        return (sp.diags(rows.astype(float)) @ walk + sp.diags((~rows).astype(float))).tocsr()

    w_in = walk_of(e, ~on_b)
    w_b = walk_of(be, on_b) if len(be) else sp.identity(nv, format="csr")

    def sweep(x: np.ndarray) -> np.ndarray:
        x = 0.5 * x + 0.5 * (w_in @ x)
        x = x + 0.5 * (w_b @ x - x)
        return x - 0.53 * (w_b @ x - x)

    return sweep, vertex_adjacency(nv, e)


def _shrink_wrap(
    x: np.ndarray, faces: np.ndarray, offset: np.ndarray, f: _BodyFields, *, iterations: int,
    smooth_weight: np.ndarray | None = None,
) -> np.ndarray:
    """Offset surface that bridges concavities: smooth, then push out to ≥ `offset` (V,)."""
    sweep, adj = _smoother(faces, len(x))
    deg = np.maximum(np.asarray(adj.sum(1)).ravel(), 1)
    avg = sp.diags(1.0 / deg) @ adj
    # First against the smoothed (cleft-free) body, then a few sweeps against the real one.
    # Smoothing strength per vertex: full on the torso (bridges the armpit and other creases),
    # weak on the sleeves, whose tubes it would only shrink and pleat.
    a = np.ones((len(x), 1)) if smooth_weight is None else smooth_weight[:, None]
    for it in range(iterations + 10):
        query = f.smooth_query if it < iterations else f.query
        x = x + a * (sweep(x) - x)
        d, c, n = query(x)
        # Push-out displacement to the offset along the body normal, averaged over neighbours
        # before it is applied: across a crease the pushes of neighbouring vertices point at
        # each other and would fold the sheet; their average points out of it.
        disp = np.where((d < offset)[:, None], c + n * offset[:, None] - x, 0.0)
        for _ in range(2):
            disp = 0.5 * disp + 0.5 * (avg @ disp)
        x = x + a * disp
        if it >= iterations:
            x = _relax_tangential(x, faces, adj)
    return _untangle(x, faces, sweep, adj, f)


def _relax_tangential(x: np.ndarray, faces: np.ndarray, adj, step: float = 0.5) -> np.ndarray:
    """Uniform Laplacian step with its normal component removed (evens out the triangles)."""
    nrm = vertex_normals(x, faces)
    delta = (adj @ x) / np.maximum(np.asarray(adj.sum(1)), 1) - x
    return x + step * (delta - (delta * nrm).sum(1, keepdims=True) * nrm)


def _untangle(x, faces, sweep, adj, f: _BodyFields, *, rounds: int = 15) -> np.ndarray:
    """Remove self-intersections left in creases by local smoothing that keeps the margin.

    Each round smooths the vertices of intersecting faces and a few rings around them (the
    crease is bridged instead of pushed apart) and pushes out, along the sheet's own normal,
    only the vertices closer to the body than the margin.
    """
    clear = COLLISION_MARGIN + 1e-3
    for _ in range(rounds):
        bad = self_intersecting_faces(x, faces)
        if _DEBUG:
            print("untangle", len(bad))
        if len(bad) == 0:
            break
        sel = np.zeros(len(x), float)
        sel[faces[bad].ravel()] = 1.0
        for _ in range(4):
            sel = np.maximum(sel, (adj @ sel > 0).astype(float))
        m = sel > 0
        for k in range(8):
            xs = sweep(x)
            if k % 2:  # alternate with tangential relaxation, which unfolds small pleats
                xs = _relax_tangential(x, faces, adj)
            x[m] = xs[m]
            # Push along the sheet's own normal: in a cleft the body normals of neighbouring
            # vertices point at each other, the smoothed sheet's normal points out of it.
            d, _, _ = f.query(x[m])
            ng = vertex_normals(x, faces)[m]
            x[m] = x[m] + ng * np.clip(clear - d, 0.0, None)[:, None]
    d, c, n = f.query(x)
    low = d < clear - 5e-4
    x[low] = c[low] + n[low] * clear
    return x


def generate_garment(
    params: GarmentParams,
    *,
    target_edge: float = 0.015,
    body: CanonicalBody | None = None,
    wrap_iterations: int = 40,
) -> GarmentTemplate:
    """Build the template mesh of one procedural garment on the canonical body.

    Args:
        params: garment parameters (see `sample_params`).
        target_edge: edge length of the output mesh [m].
        body: the canonical body (default: Anny, phenotypes 0.5, rest pose).
        wrap_iterations: smoothing/push-out sweeps of the shrink-wrap.

    Returns:
        the garment; deterministic for given params and body.
    """
    body = canonical_body() if body is None else body
    f = _fields(body)
    phi = coverage_field(params, f, body.verts)
    v, fa = clip_mesh(f.smooth_verts, body.faces, phi)
    holes = _crease_holes(params, f)
    if holes:
        v, fa = _fill_pits(v, fa, f, holes)
    # The offset stretches the sheet by a few per cent: aim the remesher a little short.
    v, fa = remesh(v, fa, target_edge=0.92 * target_edge)
    # Offsets per garment vertex from the nearest body vertex's arm-ness and height.
    _, closest, _ = f.query(v)
    from scipy.spatial import cKDTree

    nn = cKDTree(body.verts).query(closest)[1]
    arm = np.clip(f.arm[nn], 0.0, 1.0)
    chest_y = float(f.shoulders[1.0][1]) - 0.1
    ramp = np.clip((chest_y - v[:, 1]) / max(chest_y - params.hem_height, 1e-3), 0.0, 1.0)
    lateral = np.abs(f.normals[nn, 0])
    offset = (
        COLLISION_MARGIN + 1e-3
        + (1 - arm) * (params.looseness + params.flare * ramp**2 + params.width * lateral**2)
        + arm * params.sleeve_looseness
    )
    # Never offset more than ~0.4 of the free space in front of the body (the gap to the next
    # body part along the normal): arm and torso sheets then cannot cross under the armpit.
    _, c, n = f.query(v)
    gap = ray_hit_distances(body.verts, body.faces, c + 1e-4 * n, n, max_t=1.0)
    offset = np.maximum(np.minimum(offset, 0.4 * gap), COLLISION_MARGIN + 1e-3)
    weight = np.clip(1.0 - arm, 0.0, 1.0) ** 2 * 0.9 + 0.1
    # Start from the patch offset along its own normals (plus how deep the smoothed patch sank
    # into the body): a smooth tube offset along its normals cannot fold, so the sleeves are
    # nearly final here and the iterations below mostly shape the torso.
    sink = np.clip(-f.query(v)[0], 0.0, None)
    v = v + vertex_normals(v, fa) * (offset + sink)[:, None]
    v = _shrink_wrap(v, fa, offset, f, iterations=wrap_iterations, smooth_weight=weight)
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
    report = None
    for attempt in range(max_attempts):
        p = sample_params(category, seed, attempt=attempt)
        g = generate_garment(p, target_edge=target_edge, body=body)
        report = validate_garment(g.verts, g.faces, name=g.name, body=(body.verts, body.faces),
                                  margin=COLLISION_MARGIN)
        if report.ok:
            g.meta["attempt"] = attempt
            return g, attempt
    raise GarmentError(f"no valid garment for {category} seed {seed} in {max_attempts} draws; last:\n{report}")


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

"""What the procedural generator reads off the canonical body, computed once per body.

`BodyFields` (the tops) per body vertex: a smooth arm-ness (the 0/1 arm label of the skinning,
diffused over the surface), the arm coordinate along the shoulder→wrist axis, the body side and
normals; the armpit hollows and inner-elbow creases; landmarks (neck, shoulders) moved so the
armpit sits where the garment parameters were designed for; a low-pass copy of the surface the
garment patch is cut from; and distance queries against the real and the smoothed body.
`LegFields` (trousers and shorts) the same for the legs: leg-ness, the coordinate along the
hip→ankle axis, and a low-pass copy that leaves both arms and legs nearly as they are.
Positions y-up, metres, body facing +z.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from physdrape.garments.canonical import CanonicalBody
from physdrape.garments.numpy_geometry import BodyDistance, vertex_normals
from physdrape.geometry.topology import undirected_edges, vertex_adjacency

__all__ = ["BodyFields", "LegFields", "body_fields", "leg_fields"]

#: Height of the armpit hollow below the shoulder joint the parameters are designed for [m].
_PIT_BELOW_SHOULDER = 0.128
_ARM_PREFIXES = ("upperarm", "lowerarm", "wrist", "finger", "metacarpal")
_LEG_PREFIXES = ("upperleg", "lowerleg", "foot", "toe")


def _surface_walk(body: CanonicalBody) -> sp.csr_matrix:
    """The random walk over the body's edges (each row averages a vertex's neighbours)."""
    adj = vertex_adjacency(len(body.verts), undirected_edges(body.faces))
    deg = np.asarray(adj.sum(1)).ravel()
    return sp.diags(1.0 / deg) @ adj


def _soft_label(body: CanonicalBody, prefixes: tuple, walk) -> np.ndarray:
    """The 0/1 label of the vertices whose dominant bone starts with one of `prefixes`, smoothed
    over the surface: a soft label whose 0.5 level is smooth."""
    labels = np.array(body.bone_labels)
    w = np.array([lab.startswith(prefixes) for lab in labels])[body.vertex_bone].astype(np.float64)
    for _ in range(12):
        w = 0.5 * w + 0.5 * (walk @ w)
    return w


def _low_pass(v: np.ndarray, walk, weight: np.ndarray) -> np.ndarray:
    """20 Laplacian sweeps with a per-vertex strength `weight` (V,)."""
    xs = v.copy()
    for _ in range(20):
        xs = xs + weight[:, None] * (walk @ xs - xs)
    return xs


class BodyFields:
    """Per-body-vertex quantities the coverage field is built from (computed once per body)."""

    def __init__(self, body: CanonicalBody):
        self.body = body
        v = body.verts
        walk = _surface_walk(body)
        w = _soft_label(body, _ARM_PREFIXES, walk)
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
        xs = _low_pass(v, walk, 0.5 * np.clip(1.0 - w, 0.0, 1.0) ** 2)
        self.smooth_verts = xs
        self.smooth_query = BodyDistance(xs, body.faces)
        self.neck_center = joints["neck01"].copy()
        self.neck_base = float(joints["neck01"][1]) - 0.035
        self.shoulders = {sgn: joints["upperarm01" + sfx] for sfx, sgn in ((".L", 1.0), (".R", -1.0))}
        self.query = BodyDistance(body.verts, body.faces)
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


class LegFields:
    """Per-body-vertex quantities the trousers' coverage field is built from (`garments.trousers`).

    Attributes:
        leg: smooth leg-ness (the skinning's 0/1 leg label diffused over the surface) (Vb,).
        t: distance along the hip→ankle axis of the vertex's side [m] (Vb,); 0 at the hip joint.
        side: sign of x (Vb,).
        smooth_verts, smooth_query: a low-pass copy of the surface for the cut and the first
            shrink-wrap sweeps: the hips and the seat smoothed at full strength (the gluteal cleft
            filled), the legs and arms barely (smoothing shrinks a tube).
        query: distance to the real body (shared with `BodyFields`).
    """

    def __init__(self, body: CanonicalBody, fields: BodyFields):
        v = body.verts
        walk = _surface_walk(body)
        self.leg = _soft_label(body, _LEG_PREFIXES, walk)
        self.side = np.sign(v[:, 0])
        t = np.zeros(len(v))
        for sfx, sgn in ((".L", 1.0), (".R", -1.0)):
            hip = body.joints["upperleg01" + sfx]
            d = body.joints["foot" + sfx] - hip
            m = self.side == sgn
            t[m] = (v[m] - hip) @ (d / np.linalg.norm(d))
        self.t = t
        free = np.clip(1.0 - fields.arm, 0.0, 1.0) * np.clip(1.0 - self.leg, 0.0, 1.0)
        self.smooth_verts = _low_pass(v, walk, 0.5 * free**2)
        self.smooth_query = BodyDistance(self.smooth_verts, body.faces)
        self.query = fields.query


_FIELDS: dict[int, BodyFields] = {}
_LEG_FIELDS: dict[int, LegFields] = {}


def body_fields(body: CanonicalBody) -> BodyFields:
    """The fields of `body`, computed on first use and cached for the process."""
    key = id(body)
    if key not in _FIELDS:
        _FIELDS[key] = BodyFields(body)
    return _FIELDS[key]


def leg_fields(body: CanonicalBody) -> LegFields:
    """The leg fields of `body`, computed on first use and cached for the process."""
    key = id(body)
    if key not in _LEG_FIELDS:
        _LEG_FIELDS[key] = LegFields(body, body_fields(body))
    return _LEG_FIELDS[key]

"""Layer order: the outer piece of a multi-piece garment stays outside the inner one.

The physics has no self-collision, so where a top lies over trousers (or a jacket over a shirt)
nothing stops one layer from passing through the other. Where two pieces overlap on the
template, each outer vertex o is paired with the inner vertex i under it; the pair keeps o at
least δ outside i along the body's outward normal n at i (held fixed), a one-sided penalty:

    E_layer = Σ_p ½ k_p ReLU(δ_p − n_p·(x_o − x_i))²                          [J]
    f_o = k_p ReLU(·) n_p,   f_i = −f_o                                         [N]
    ∇²: [[H, −H], [−H, H]], H = k_p n_p n_pᵀ where the pair is active, else 0   (PSD)

The inner surface is taken as the plane through x_i normal to n_i, which holds while the layers
slide a few centimetres over each other. k_p [N/m] per pair.

Pieces slide farther than that in a long minimisation (a jacket settling down over trousers), past
the pairs found on the template, and pass through each other where no pair holds them. A layer
order built with each vertex's piece, its distance from the body on the template and the faces
(`LayerOrder.follows`) is completed by pairs found at the current positions (`followed`,
`follow_pairs`): each vertex near another piece of its garment (within `FOLLOW_RADIUS`) that lies
over or under that piece's surface (at most `FOLLOW_ASIDE` beside the closest face) is held on the
side of it where it is, the face's nearest corner its partner and the face's normal the pair's:
the plane through the corner is the face's own, so the pair holds the vertex off the surface
itself, not off a plane through a vertex beside it, which on the body's curves (collar,
shoulders) lies centimetres above the surface. Such pairs keep the pieces from passing through
each other from where they are (they do not undo a crossing), and hold whichever piece lies
locally on top (a tie under its collar and over its shirt). The gap comes from the template's
distances as before (`LayerOrder.with_pairs`). The oracle finds them as it goes
(`physics.oracle`), and so does the measured energy of every drape (`physics.energy`).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import torch
from torch import Tensor

from physdrape.geometry.closest_point import closest_point_on_indexed_triangles
from physdrape.geometry.neighbours import nearest_within
from physdrape.tensor_memo import TensorMemo

__all__ = ["DEFAULT_LAYER_GAP", "DEFAULT_LAYER_STIFFNESS", "FOLLOW_ASIDE", "FOLLOW_NEIGHBOURS", "FOLLOW_RADIUS",
           "MIN_LAYER_GAP", "LayerOrder", "follow_pairs", "followed", "layer_energy", "layer_forces",
           "layer_pair_blocks", "layer_shortfall", "push_outer_out"]

#: Stiffness of one layer pair [N/m].
DEFAULT_LAYER_STIFFNESS = 1000.0
#: Normal separation δ kept between layers authored at least this far apart [m] (fabric and the air
#: between layers); layers authored closer keep their own separation (`LayerOrder.build`).
DEFAULT_LAYER_GAP = 4e-3
#: Least gap [m] of a pair authored closer than `DEFAULT_LAYER_GAP` (`LayerOrder.build`).
MIN_LAYER_GAP = 1e-3
#: Largest distance between paired vertices [m] (`garments.layering.layer_pairs`) or between a
#: vertex and the surface it is held against (`follow_pairs`): pieces hanging loose over each other
#: come into contact during a drape; measured on the MakeHuman suits, 4 cm covers them.
FOLLOW_RADIUS = 0.04
#: On the template each vertex is paired with this many nearest vertices of the other piece: one
#: leaves the inner sheet free to bulge through between paired vertices, three hold the surface
#: around it; `follow_pairs` searches the faces around as many.
FOLLOW_NEIGHBOURS = 3
#: Largest offset [m] of a vertex from the closest point of another piece's surface across that
#: face's normal (`follow_pairs`): 0 over a face's interior; beyond the surface's border it grows,
#: and there the vertex is beside the piece, not over or under it.
FOLLOW_ASIDE = 0.005
#: Passes of `push_outer_out`: a piece pushed out may be the inner piece of another pair (a jacket
#: over a shirt over trousers), which the next pass then pushes.
PUSH_PASSES = 3

#: Each layer order's faces table (`_faces_of_vertices`), kept per faces tensor: `follow_pairs`
#: runs at every full body query of a solve and at every search of the oracle, on the same faces.
_FACE_TABLES = TensorMemo(size=8)


@dataclass(frozen=True)
class LayerOrder:
    """Outer-over-inner vertex pairs of a packed garment batch.

    Attributes:
        pairs: (P, 2) int64 [outer, inner] vertex indices (into the batch's ΣV vertices).
        normal: unit outward normal n of the pair (P, 3): the body's at the inner vertex on the
            template's pairs, the face's (`follow_pairs`) on pairs found again.
        gap: the least separation δ [m] (P,).
        stiffness: k [N/m] (P,).
        piece: each vertex's piece (ΣV,) int64, numbered across the batch (−1: a vertex of a garment
            without a layer order), or None: the pairs stay those of the template.
        together: (K, K) bool, True where two pieces belong to one garment (`follow_pairs` pairs
            their vertices).
        depth: each vertex's distance from the body on the template [m] (ΣV,): a pair's gap is
            |depth[o] − depth[i]|, clamped as in `build`.
        faces: the faces of the garments with a layer order (F, 3) int64 (batch vertex indices).
        fixed: how many of the pairs, first, are the template's (None: all); `with_pairs` replaces
            the rest.
    """

    pairs: Tensor
    normal: Tensor
    gap: Tensor
    stiffness: Tensor
    piece: Tensor | None = None
    together: Tensor | None = None
    depth: Tensor | None = None
    faces: Tensor | None = None
    fixed: int | None = None

    def to(self, dtype: torch.dtype | None = None, *, device: torch.device | str | None = None) -> LayerOrder:
        def move(t, floating):
            return None if t is None else t.to(device=device, dtype=dtype if floating else None)

        return LayerOrder(self.pairs.to(device=device), self.normal.to(device=device, dtype=dtype),
                          self.gap.to(device=device, dtype=dtype), self.stiffness.to(device=device, dtype=dtype),
                          move(self.piece, False), move(self.together, False), move(self.depth, True),
                          move(self.faces, False), self.fixed)

    @property
    def follows(self) -> bool:
        """Whether `followed` completes the pairs at the current positions."""
        return self.piece is not None and self.faces is not None

    def with_pairs(self, pairs: Tensor, normal: Tensor) -> LayerOrder:
        """The template's pairs and these [outer, inner] pairs (P, 2) with their normals (P, 3)
        (replacing those `with_pairs` added before): gaps from the template's distances (`depth`),
        the stiffness of the first pair (`DEFAULT_LAYER_STIFFNESS` without any)."""
        keep = len(self.pairs) if self.fixed is None else self.fixed
        gap = (self.depth[pairs[:, 0]] - self.depth[pairs[:, 1]]).abs().to(normal.dtype).clamp(MIN_LAYER_GAP,
                                                                                            DEFAULT_LAYER_GAP)
        k = self.stiffness[:1] if len(self.stiffness) else torch.full((1,), DEFAULT_LAYER_STIFFNESS,
                                                                         device=normal.device)
        stiffness = k.to(normal.dtype).expand(len(pairs))
        return replace(self, pairs=torch.cat([self.pairs[:keep], pairs.to(self.pairs.device)]),
                       normal=torch.cat([self.normal[:keep], normal]), gap=torch.cat([self.gap[:keep], gap]),
                       stiffness=torch.cat([self.stiffness[:keep], stiffness]), fixed=keep)

    @staticmethod
    def build(pairs: Tensor, normal: Tensor, *, separation: Tensor | None = None,
              stiffness: float = DEFAULT_LAYER_STIFFNESS) -> LayerOrder:
        """Pairs (P, 2) with their inner normals (P, 3) and one stiffness [N/m]. The gap of a pair is
        its `separation` on the template [m] (P,) clamped to [`MIN_LAYER_GAP`, `DEFAULT_LAYER_GAP`]
        (layers authored closer than the default stay as close, not pushed apart), or
        `DEFAULT_LAYER_GAP` without it."""
        full = torch.ones(len(pairs), dtype=normal.dtype, device=normal.device)
        gap = DEFAULT_LAYER_GAP * full if separation is None else separation.to(full).clamp(MIN_LAYER_GAP,
                                                                                            DEFAULT_LAYER_GAP)
        return LayerOrder(pairs=pairs.to(device=normal.device), normal=normal, gap=gap, stiffness=stiffness * full)


def _faces_of_vertices(faces: Tensor, num_verts: int) -> Tensor:
    """Each vertex's faces (num_verts, D) int64, −1 where it has fewer than the most (D) (a vertex
    of no face: a row of −1)."""
    vertex = faces.reshape(-1)
    face = torch.arange(len(faces), device=faces.device).repeat_interleave(3)
    order = torch.argsort(vertex, stable=True)
    vertex, face = vertex[order], face[order]
    counts = torch.bincount(vertex, minlength=num_verts)
    slot = torch.arange(len(vertex), device=faces.device) - (torch.cumsum(counts, 0) - counts)[vertex]
    table = torch.full((num_verts, max(int(counts.max()), 1)), -1, dtype=torch.int64, device=faces.device)
    table[vertex, slot] = face
    return table


def _onto_surface(x: Tensor, points: Tensor, near: Tensor, faces: Tensor, around: Tensor) -> tuple[Tensor, Tensor]:
    """Pairs of `points` (M,) against the faces around their nearest vertices `near` (M, k) (−1:
    none) of another piece: (pairs [outer, inner] (M', 2), normals (M', 3)): the point and the
    closest face's nearest corner, the point outer where it lies on the side the face's normal
    points to; the points farther than `FOLLOW_RADIUS` from those faces or more than
    `FOLLOW_ASIDE` beside them left out."""
    candidates = torch.where(near[:, :, None] >= 0, around[near.clamp_min(0)], -1).flatten(1)  # (M, k D)
    valid = candidates >= 0
    m, c = candidates.shape
    at = x[points][:, None, :].expand(m, c, 3).reshape(-1, 3)
    closest, bary = closest_point_on_indexed_triangles(at, x, faces[candidates.clamp_min(0).reshape(-1)])
    dist = (at - closest).norm(dim=-1).reshape(m, c).masked_fill(~valid, float("inf"))
    best = dist.argmin(1)
    face = candidates[torch.arange(m, device=x.device), best]
    pick = best + c * torch.arange(m, device=x.device)
    offset, weight = at[pick] - closest[pick], bary[pick]
    corners = x[faces[face]]
    normal = torch.nn.functional.normalize(torch.linalg.cross(corners[:, 1] - corners[:, 0],
                                                              corners[:, 2] - corners[:, 0]), dim=-1)
    along = (offset * normal).sum(-1)
    aside = (offset - along[:, None] * normal).norm(dim=-1)
    keep = (dist.min(1).values <= FOLLOW_RADIUS) & (aside <= FOLLOW_ASIDE)
    corner = faces[face, weight.argmax(1)]
    above = along >= 0
    pairs = torch.stack([torch.where(above, points, corner), torch.where(above, corner, points)], 1)
    return pairs[keep], normal[keep]


@torch.no_grad()
def follow_pairs(x: Tensor, layers: LayerOrder) -> tuple[Tensor, Tensor]:
    """Pairs that hold each vertex on the side of the other pieces' surfaces where it is at x
    (ΣV, 3) [m]: for every two pieces of one garment (`LayerOrder.together`), each vertex of
    either against the closest of the faces around its `FOLLOW_NEIGHBOURS` nearest vertices of the
    other (within `FOLLOW_RADIUS`, at most `FOLLOW_ASIDE` beside it), paired with that face's
    nearest corner, the face's normal the pair's. Returns ([outer, inner] pairs (P, 2) int64,
    normals (P, 3)). Needs `layers.follows`."""
    piece, x = layers.piece, x.detach()
    partners = layers.together & ~torch.eye(len(layers.together), dtype=torch.bool, device=layers.together.device)
    points_of, near_of = [], []
    for q in partners.any(0).nonzero()[:, 0].tolist():  # one search per piece: its partners' vertices against it
        others = (piece == q).nonzero()[:, 0]
        points = ((piece >= 0) & partners[piece.clamp_min(0), q]).nonzero()[:, 0]
        near = torch.full((len(points), FOLLOW_NEIGHBOURS), -1, dtype=torch.int64, device=x.device)
        a, b = nearest_within(x[points], x[others], k=FOLLOW_NEIGHBOURS, radius=FOLLOW_RADIUS)
        slot = torch.arange(len(a), device=x.device) - torch.searchsorted(a, a)  # a is sorted
        near[a, slot] = others[b]
        has = (near >= 0).any(1)
        points_of.append(points[has])
        near_of.append(near[has])
    points = torch.cat(points_of) if points_of else torch.zeros(0, dtype=torch.int64, device=x.device)
    if not len(points):
        return torch.zeros(0, 2, dtype=torch.int64, device=x.device), x.new_zeros(0, 3)
    around = _FACE_TABLES.get(layers.faces, lambda faces: _faces_of_vertices(faces, int(faces.max()) + 1))
    return _onto_surface(x, points, torch.cat(near_of), layers.faces, around)


def followed(layers: LayerOrder, x: Tensor) -> LayerOrder:
    """The layer order's template pairs completed by those found at x (ΣV, 3) (`follow_pairs`);
    `layers` itself where it does not follow."""
    if not layers.follows:
        return layers
    pairs, normal = follow_pairs(x, layers)
    return layers.with_pairs(pairs, normal.to(layers.normal.dtype))


def layer_shortfall(x: Tensor, layers: LayerOrder) -> Tensor:
    """ReLU(δ − n·(x_o − x_i)) per pair [m], (..., P)."""
    d = x[..., layers.pairs[:, 0], :] - x[..., layers.pairs[:, 1], :]
    return (layers.gap.to(x.dtype) - (d * layers.normal.to(x.dtype)).sum(-1)).clamp_min(0.0)


def layer_energy(x: Tensor, layers: LayerOrder) -> Tensor:
    """½ k ReLU(δ − n·(x_o − x_i))² per pair [J], x (..., V, 3) → (..., P)."""
    return 0.5 * layers.stiffness.to(x.dtype) * layer_shortfall(x, layers) ** 2


def layer_forces(x: Tensor, layers: LayerOrder) -> Tensor:
    """f = −∇E_layer on every vertex [N], x (..., V, 3) → (..., V, 3)."""
    f = (layers.stiffness.to(x.dtype) * layer_shortfall(x, layers))[..., None] * layers.normal.to(x.dtype)  # on o
    out = torch.zeros_like(x).index_add_(-2, layers.pairs[:, 0], f)
    return out.index_add_(-2, layers.pairs[:, 1], -f)


def layer_pair_blocks(x: Tensor, layers: LayerOrder) -> Tensor:
    """H per pair (P, 3, 3) [N/m]: k n nᵀ where the pair is active, else 0; x (V, 3)."""
    n = layers.normal.to(x.dtype)
    active = (layer_shortfall(x, layers) > 0).to(x.dtype) * layers.stiffness.to(x.dtype)
    return active[:, None, None] * n[:, :, None] * n[:, None, :]


def push_outer_out(x: Tensor, layers: LayerOrder, allowed: Tensor | None = None) -> Tensor:
    """x (V, 3) [m] with each pair's outer vertex pushed out along the pair's normal n until its
    shortfall ReLU(δ − n·(x_o − x_i)) is at most `allowed` [m] (P,) (None: 0, the layers in
    order). An outer vertex in several pairs takes the largest push along their push-weighted
    mean normal; up to `PUSH_PASSES` passes for layers over layers. Not a term of the energy: a
    geometric step of the kinematic start (`pipeline`, allowed None) and of the collision
    handler (allowed: the shortfall before its push); outward only, differentiable in x."""
    outer, normal = layers.pairs[:, 0], layers.normal.to(x.dtype)
    for _ in range(PUSH_PASSES):
        excess = layer_shortfall(x, layers)
        if allowed is not None:
            excess = excess - allowed
        excess = excess.clamp_min(0.0)
        if not bool((excess > 0).any()):
            break
        size = x.new_zeros(x.shape[0]).scatter_reduce(0, outer, excess, "amax", include_self=True)
        direction = torch.nn.functional.normalize(torch.zeros_like(x).index_add(0, outer, excess[:, None] * normal),
                                                  dim=1)
        x = x + size[:, None] * direction
    return x

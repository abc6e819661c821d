"""The learnable collision handler (paper Eq. 11): push vertices out along the body normal, then
the faces whose centroids still dip into the body, then what those pushes left inside where two
parts of the body overlap, then the outer layers that a push drove into the layer under them."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from physdrape.geometry.distance_bound import DistanceBound
from physdrape.geometry.proximity import BodySurface
from physdrape.physics.contact import DEFAULT_MARGIN
from physdrape.physics.layers import LayerOrder, layer_shortfall, push_outer_out


class CollisionHandler(nn.Module):
    """x*_i = x_i + δ · ReLU(ε − d_i) · n_i with δ = 1 + softplus(ρ) ≥ 1; then a centroid pass.

    d_i and n_i come from the exact closest point on the posed body triangles. Which triangle is
    closest is not differentiated; x* is differentiable in x (and δ).

    The paper's handler moves vertices only. A large triangle over a convex part of the body can
    have all three vertices ε outside and its interior inside (coarse garments, with edges of
    several centimetres, do). The centroid pass (when `faces` are given and ε_c > 0) takes each face whose centroid c_f is
    closer than ε_c to the body, with push p_f = ε_c − d(c_f) along the normal n_f there, and
    moves each of its vertices by max_f p_f along the p-weighted mean direction of its faces'
    n_f. One pass: a lone face's centroid ends at ε_c; where pushed faces share vertices and
    their normals differ, a centroid can end between 0 and ε_c. Pushes are outward, so no vertex
    comes closer than ε.

    Where two parts of a posed body interpenetrate, a push along the normal can land inside the
    other part; what was inside before the handler is checked again after these passes and moved
    out by the shortest of a set of offsets of a few millimetres (`_free_stuck`); what is still
    inside then goes back where it was (cloth caught deep between two parts pressed together,
    which no push frees: pushing it only tears it from its neighbours).

    A multi-piece garment's layer order (`physics.layers`) is the last pass (when `layers` are
    given): a push that moves an inner piece's vertex out toward the piece over it would leave
    the pieces crossed (the handler runs after the solver, so nothing would undo it). Each outer
    vertex o is pushed out along its pair's normal n by the growth of the pair's shortfall
    ReLU(δ − n·(x_o − x_i)) over its value before the handler, so the handler never adds to the
    layer-order energy of a pair (`physics.layers.push_outer_out`).

    Args:
        margin: ε [m]; a vertex ends at least ε outside the body along n when δ ≥ 1.
        delta: initial δ (> 1).
        centroid_margin: ε_c [m] of the centroid pass (0: off, the paper's handler).
    """

    def __init__(self, *, margin: float = DEFAULT_MARGIN, delta: float = 1.05, centroid_margin: float = 0.0) -> None:
        super().__init__()
        if not margin > 0 or not delta > 1 or not centroid_margin >= 0:
            raise ValueError(f"need margin > 0, delta > 1 and centroid_margin ≥ 0, got margin={margin}, "
                             f"delta={delta}, centroid_margin={centroid_margin}")
        self.margin = margin
        self.centroid_margin = centroid_margin
        self.delta_raw = nn.Parameter(torch.tensor(math.log(math.expm1(delta - 1.0))))

    @property
    def delta(self) -> Tensor:
        return 1.0 + F.softplus(self.delta_raw)

    def forward(self, x: Tensor, bodies: BodySurface, body_index: Tensor, *, delta: Tensor | float | None = None,
                faces: Tensor | None = None, layers: LayerOrder | None = None,
                bound: DistanceBound | None = None) -> Tensor:
        """Project x (ΣV, 3) [m] out of the bodies; `body_index` (ΣV,) names each vertex's body;
        `faces` (ΣF, 3) (global vertex indices) enable the centroid pass, `layers` the layer pass.

        `delta` overrides the learned δ (the Post-Col ablation uses a plain δ = 1). `bound`: a
        `DistanceBound` of the vertices and then the face centroids (the solver's last full body
        query): only the vertices and centroids it leaves within their margins are queried (the
        others are pushed by nothing, values and gradients alike).
        """
        before = x
        num_verts = x.shape[0]
        delta = self.delta.to(x.dtype) if delta is None else delta
        rows, query = bodies.query_within(x, self.margin, body_index=body_index,
                                          bound=None if bound is None else bound.part(0, num_verts))
        push = (delta * (self.margin - query.signed_distance).clamp_min(0.0))[:, None] * query.normal
        x = x + push if rows is None else x.index_add(0, rows, push)
        suspects = torch.nonzero(query.inside).flatten()  # inside before the push
        suspects = suspects if rows is None else rows[suspects]
        if faces is not None and self.centroid_margin > 0:
            x, dipped = self._push_centroids(x, faces, bodies, body_index,
                                             None if bound is None else bound.part(num_verts, num_verts + faces.shape[0]))
            suspects = torch.cat([suspects, faces[dipped].reshape(-1)])
        if suspects.numel():
            x = self._free_stuck(x, faces, bodies, body_index, suspects)
            x = _trapped_left_where_they_were(x, before, bodies, body_index, suspects)
        if layers is not None and len(layers.pairs):
            x = push_outer_out(x, layers, allowed=layer_shortfall(before, layers))
        return x

    def _push_centroids(self, x: Tensor, faces: Tensor, bodies: BodySurface, body_index: Tensor,
                        bound: DistanceBound | None) -> tuple[Tensor, Tensor]:
        """The centroid pass; also the faces (int64 rows of `faces`) whose centroids were inside."""
        centroids, owner = x[faces].mean(dim=1), body_index[faces[:, 0]]
        rows, query = bodies.query_within(centroids, self.centroid_margin, body_index=owner, bound=bound)
        inside = torch.nonzero(query.inside).flatten()
        if rows is not None:
            faces, inside = faces[rows], rows[inside]
        push = (self.centroid_margin - query.signed_distance).clamp_min(0.0)
        hit = push > 0
        if not bool(hit.any()):
            return x, inside
        verts = faces[hit].reshape(-1)
        p = push[hit].repeat_interleave(3)
        size = x.new_zeros(x.shape[0]).scatter_reduce(0, verts, p, "amax", include_self=True)
        weighted = (push[hit, None] * query.normal[hit]).repeat_interleave(3, dim=0)
        direction = F.normalize(torch.zeros_like(x).index_add(0, verts, weighted), dim=1)
        return x + size[:, None] * direction, inside

    def _free_stuck(self, x: Tensor, faces: Tensor | None, bodies: BodySurface, body_index: Tensor,
                    suspects: Tensor) -> Tensor:
        """Move out what the passes along the body normal left inside: the vertices `suspects`
        (int64; those that were inside before the handler, and those of faces whose centroids
        were) and, when `faces` are given, the faces around them.

        Where two parts of a posed body interpenetrate (a forearm sunk into the upper arm), the closest
        body triangle of a point in the overlap can be one buried in the other part, and a push
        along its normal lands inside that part (repeating the push oscillates between the
        two). A stuck vertex instead takes the shortest offset among `EXIT_DIRECTIONS` ×
        `EXIT_RADII` that puts it at least ε outside (`exit_offsets`); a stuck face's three
        vertices take the offset that puts its centroid ε_c outside; a vertex of several takes
        the longest (`longest_per_row`). The offsets are constants in the gradient (x* stays
        differentiable in x). Up to `FREE_ROUNDS` rounds, each checking the vertices moved and the
        faces around them again; over all rounds no vertex moves farther than the longest exit
        radius. What finds no way out that near (cloth caught where an arm is pressed into the
        torso, or between the thighs: a static drape cannot free it) is not moved here, and
        `forward` puts it back where it was before the handler: B2G says so, rather than the
        garment being torn toward some distant exit.
        """
        start = x.detach()
        reach = EXIT_RADII[-1]
        candidates = torch.zeros(x.shape[0], dtype=torch.bool, device=x.device)
        candidates[suspects] = True
        for _ in range(FREE_ROUNDS):
            rows = torch.nonzero(candidates).flatten()
            with torch.no_grad():
                stuck = rows[bodies.query(x[rows].detach(), body_index=body_index[rows]).inside]
                offsets = exit_offsets(x[stuck].detach(), bodies, body_index[stuck], self.margin)
                if faces is not None:
                    near = faces[candidates[faces].any(dim=1)]
                    centroids = x[near].detach().mean(dim=1)
                    flat = near[bodies.query(centroids, body_index=body_index[near[:, 0]]).inside]
                    if flat.shape[0]:
                        offset = exit_offsets(x[flat].detach().mean(dim=1), bodies, body_index[flat[:, 0]],
                                              self.centroid_margin or self.margin)
                        stuck = torch.cat([stuck, flat.reshape(-1)])
                        offsets = torch.cat([offsets, offset.repeat_interleave(3, dim=0)])
            if not stuck.numel():
                break
            with torch.no_grad():
                moved = x.detach() + longest_per_row(stuck, offsets, x.shape[0]) - start
                length = moved.norm(dim=1, keepdim=True)
                moved = moved * (reach / length.clamp_min(reach))  # at most `reach` from where it started
                shift = start + moved - x.detach()
            x = x + shift
            candidates = torch.zeros_like(candidates)
            candidates[stuck] = True
        return x


def _trapped_left_where_they_were(x: Tensor, before: Tensor, bodies: BodySurface, body_index: Tensor,
                                  suspects: Tensor) -> Tensor:
    """x with the vertices of `suspects` that are still inside the body back where they were
    before the handler (`before`). What neither the push along the normal nor an exit offset got
    out lies where two parts of the body sink into each other (cloth caught between the thighs, or
    between an arm and the torso): the push there only carries a vertex from one part into the
    other, opposite to its neighbours', and tears the cloth."""
    rows = torch.unique(suspects)
    with torch.no_grad():
        trapped = rows[bodies.query(x[rows].detach(), body_index=body_index[rows]).inside]
    if not trapped.numel():
        return x
    mask = torch.zeros(x.shape[0], 1, dtype=torch.bool, device=x.device)
    mask[trapped] = True
    return torch.where(mask, before, x)


@torch.no_grad()
def longest_per_row(rows: Tensor, offsets: Tensor, num_rows: int) -> Tensor:
    """A (num_rows, 3) field that gives each row of `rows` (M,) int64 the longest of its offsets
    (M, 3) (on a tie the first given) and every other row zero. A vertex stuck itself and in
    several stuck faces takes one offset, the farthest any of them asks for: their sum would
    carry it as many times as far."""
    length = offsets.norm(dim=1)
    order = torch.argsort(length, descending=True, stable=True)
    order = order[torch.argsort(rows[order], stable=True)]  # by row, longest first within a row
    ranked = rows[order]
    first = torch.ones_like(ranked, dtype=torch.bool)
    first[1:] = ranked[1:] != ranked[:-1]
    field = offsets.new_zeros(num_rows, 3)
    field[ranked[first]] = offsets[order[first]]
    return field


#: Rounds of `CollisionHandler._free_stuck`.
FREE_ROUNDS = 3
#: Offsets [m] tried for a point stuck inside the body, shortest first.
EXIT_RADII = (2e-3, 4e-3)


def _exit_directions() -> Tensor:
    """The 42 unit directions of a once-subdivided icosahedron (float64)."""
    t = (1.0 + 5.0 ** 0.5) / 2.0
    base = torch.tensor([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t],
                         [0, 1, -t], [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=torch.float64)
    base = F.normalize(base, dim=1)
    close = (base @ base.T) > 0.4  # the 30 edges: neighbours at 63.4°
    i, j = torch.nonzero(torch.triu(close, diagonal=1), as_tuple=True)
    return torch.cat([base, F.normalize(base[i] + base[j], dim=1)])


EXIT_DIRECTIONS = _exit_directions()


@torch.no_grad()
def exit_offsets(points: Tensor, bodies: BodySurface, body_index: Tensor, clearance: float) -> Tensor:
    """For each point (M, 3) inside the body, the shortest offset (M, 3) [m] among
    `EXIT_DIRECTIONS` × `EXIT_RADII` that puts it at least `clearance` outside; where none does,
    the one that ends farthest out if that is outside at all, else zero: a point with no way out
    within the longest radius (cloth caught where an arm presses into the torso) is not thrown
    across the body's overlap."""
    dirs = EXIT_DIRECTIONS.to(points)
    radii = torch.tensor(EXIT_RADII, dtype=points.dtype, device=points.device)
    steps = (radii[:, None, None] * dirs[None]).reshape(-1, 3)  # radius-major: shortest first
    trial = points[:, None, :] + steps[None]
    owner = body_index[:, None].expand(-1, steps.shape[0]).reshape(-1)
    depth = bodies.query(trial.reshape(-1, 3), body_index=owner).signed_distance
    depth = depth.reshape(points.shape[0], len(EXIT_RADII), dirs.shape[0])
    clear = depth >= clearance
    reached = clear.any(dim=2)  # (M, radii)
    # the shortest radius with a clear trial, and there the direction that ends farthest out
    shortest = reached.to(torch.int8).argmax(dim=1)
    at = depth[torch.arange(points.shape[0], device=points.device), shortest]
    best = shortest * dirs.shape[0] + at.argmax(dim=1)
    farthest = depth.flatten(1).argmax(dim=1)
    offsets = steps[torch.where(reached.any(dim=1), best, farthest)]
    out = depth.flatten(1).amax(dim=1) > 0  # some trial at least leaves the body
    return torch.where(out[:, None], offsets, torch.zeros_like(offsets))

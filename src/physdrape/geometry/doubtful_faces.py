"""Where a body's pseudo-normal sign may be wrong: the faces near buried vertices and holes
(`BodySurface.doubtful_faces`, which caches the result per body position)."""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.geometry.body_bvh import BodyBVH

#: How far from a buried vertex v (or a hole) the pseudo-normal sign is in doubt at a vertex u, in
#: multiples of e_u + e_v, each vertex's e its longest edge among the faces around it: a face F
#: that a face G of another part of the body crosses, at a point c, has G's vertex v beyond F
#: buried, and every vertex u of F, or of a face sharing a vertex with F, lies within e_F of c,
#: with v within e_G of c, so |u − v| ≤ e_u + e_v; twice that for a margin (a crossing face's
#: first vertex past F may lie too close to F's surface for its probe to be inside).
DOUBT_REACH = 2.0
#: A body vertex is buried when the point this far [m] out along its normal is inside the body.
PROBE_OFFSET = 1e-4
#: A probe's outward ray enters the surface head on where the cosine between the ray and the
#: outward normal of the first face it hits is below −ENTERING (not grazing it).
ENTERING = 0.1


@torch.no_grad()
def doubtful_faces(verts: Tensor, faces: Tensor, vertex_normals: Tensor, border: Tensor, bvh: BodyBVH, *,
                   threads: int | None, winding_accuracy: float) -> Tensor:
    """The faces (B, Fb) bool of bodies verts (B, Vb, 3) [m] (triangles faces (Fb, 3), unit
    angle-weighted vertex normals (B, Vb, 3), the vertices on a hole's border, their BVHs built
    with the winding number) near which the pseudo-normal sign may be wrong.

    A body vertex is *buried* when a point just outside it (`PROBE_OFFSET` along its normal) has
    winding number > 0.5: another part of the body covers it (posed limbs that interpenetrate).
    On a closed surface the winding number is taken only where the probe's outward ray cannot
    decide: a probe whose ray crosses nothing, or first enters the surface head on (`ENTERING`),
    is outside (exact unless one part holds another's surface inside it). Vertices on the border
    of a hole count as buried too (and there every probe gets the winding number). A face is
    doubtful when one of its vertices u lies within `DOUBT_REACH` · (e_u + e_v) of a buried vertex
    v, e the longest edge of the faces around a vertex (the edges where the body crosses itself,
    not the body's longest). Away from doubtful faces the surface is one closed, consistently
    oriented sheet, on which the pseudo-normal of the closest feature gives the exact sign.
    """
    num_bodies, num_verts = verts.shape[:2]
    normals = vertex_normals.reshape(-1, 3)
    probe = (verts.reshape(-1, 3) + PROBE_OFFSET * normals).to(torch.float32).contiguous()
    owner = torch.arange(num_bodies, dtype=torch.int32, device=verts.device).repeat_interleave(num_verts)

    def winding_inside(rows: Tensor | None) -> Tensor:
        points, body = (probe, owner) if rows is None else (probe[rows].contiguous(), owner[rows].contiguous())
        return bvh.closest_faces(points, body, winding_accuracy=winding_accuracy, threads=threads, winding=True)[1]

    if border.numel():  # a hole: the winding number of every probe
        buried = winding_inside(None)
    else:
        # On a closed surface the winding number at a point is the signed count of the surface's
        # crossings along any ray from it (+1 for each exit, −1 for each entry): a probe whose
        # outward ray crosses nothing has winding number 0 and is not buried; one whose ray first
        # enters the surface head on (`ENTERING`) is outside the part it enters, and outside
        # every other part unless one part holds another's surface inside it (parts nested two
        # deep, which posed limbs do not make). Only the rest get the winding number: the probes
        # whose ray first leaves the surface (the buried ones) or grazes it, a few dozen of an
        # Anny body's 13k vertices; the probes under an arm, whose rays enter the arm, about a
        # sixth, do not (a winding number costs several times a ray).
        hit, facing = bvh.ray_hits(probe, owner, normals.to(torch.float32).contiguous(), threads=threads)
        crossed = torch.nonzero(hit & (facing > -ENTERING))[:, 0]
        buried = torch.zeros(probe.shape[0], dtype=torch.bool, device=verts.device)
        if crossed.numel():
            buried[crossed] = winding_inside(crossed)
    buried = buried.reshape(num_bodies, num_verts)
    buried[:, border] = True
    a, b, c = (verts.index_select(1, faces[:, k]) for k in range(3))
    longest = torch.maximum(torch.maximum((b - a).square().sum(-1), (c - b).square().sum(-1)),
                            (a - c).square().sum(-1)).sqrt()  # each face's longest edge (B, Fb)
    reach = verts.new_zeros(num_bodies, num_verts).scatter_reduce(  # e of each vertex (B, Vb)
        1, faces.reshape(1, -1).expand(num_bodies, -1), longest.repeat_interleave(3, dim=1), "amax")
    near = torch.zeros(num_bodies, num_verts, dtype=torch.bool, device=verts.device)
    for b in range(num_bodies):
        centres = torch.nonzero(buried[b])[:, 0]
        for start in range(0, centres.shape[0], 1024):  # bounded memory: (Vb, 1024) distances
            some = centres[start:start + 1024]
            radius = DOUBT_REACH * (reach[b][:, None] + reach[b, some][None, :])  # (Vb, k)
            within = torch.cdist(verts[b], verts[b, some]) <= radius
            near[b] |= within.any(dim=1)
    return near[:, faces].any(dim=-1)

"""Exact closest point on triangles, and the normal and signed distance there (NVIDIA Warp
kernels, batched, differentiable).

The geometry half of the body-surface queries (`geometry.proximity`): the BVH finds the closest
triangle of each point, `closest_surface_points` computes in one launch the closest point on it in
float64, the angle-weighted pseudo-normal of the face, edge or vertex it lies on, the sign of the
point against it, the outward normal and the signed distance. `closest_point_on_indexed_triangles`
and `closest_point_on_triangle` compute the closest point alone, on triangles given by rows of a
vertex table or by their corners (the garment sizing and the skinning transfer, on candidate
triangles of their own); `walk_to_closest_faces` finds a point's closest triangle near one it
starts from (a body query of points that moved a little, instead of the BVH search); the
kernels share one closest-point function, and the walk and the surface point are functions that
the contact's plane-following kernel calls too (`physics.contact_kernels`).

One kernel launch per call replaces a chain of a few dozen torch ops over the points (region
tests, selections, gathers, norms, signs), each costing more in per-op overhead than in
arithmetic; the kernels run on the CPU (compiled native code) or on CUDA, wherever the tensors
live.

Differentiation: each kernel is wrapped in a `torch.autograd.Function` whose backward is the
kernel's adjoint, which Warp generates from the same source: the exact derivative of the region's
formula (a face's plane projection, an edge's line projection, a vertex), w.r.t. the points and
the corners. The pseudo-normal and the sign are not differentiated. Double backward is not
supported.

Numerics: float64 whatever the inputs' dtype (they are converted in, the results out).
"""

# No `from __future__ import annotations` here: Warp reads the kernels' annotations as objects.

from dataclasses import dataclass

import torch
from torch import Tensor

from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

#: Most moves of a walk over the triangles' rings (`walk_to_closest_faces`).
WALK_MOVES = 4

__all__ = ["WALK_MOVES", "SurfaceArrays", "SurfacePoints", "closest_point_on_indexed_triangles",
           "closest_point_on_triangle", "closest_surface_points", "kernels", "walk_to_closest_faces"]


@defined_once
def kernels() -> dict:
    """Define the kernels (first call only; Warp caches the compiled code on disk), with the
    functions of a point's walk and closest surface point that other kernels call
    (`physics.contact_kernels`)."""
    wp = warp()
    f64 = wp.float64

    @wp.func
    def ratio(num: wp.float64, den: wp.float64):
        """num / den where den ≠ 0, else 0 (the denominator of an unselected region can vanish;
        dividing by a safe one keeps inf out of the adjoint)."""
        ok = den != f64(0.0)
        return wp.where(ok, num / wp.where(ok, den, f64(1.0)), f64(0.0))

    @wp.func
    def closest_bary(x: wp.vec3d, a: wp.vec3d, b: wp.vec3d, c: wp.vec3d):
        """Barycentric coordinates (wa, wb, wc) of the closest point to x on triangle (a, b, c)
        (Ericson, Real-Time Collision Detection, Sec. 5.1.5). A coordinate is exactly zero when
        the point lies on the opposite edge, two are at a vertex."""
        ab = b - a
        ac = c - a
        ap = x - a
        bp = x - b
        cp = x - c
        d1 = wp.dot(ab, ap)
        d2 = wp.dot(ac, ap)
        d3 = wp.dot(ab, bp)
        d4 = wp.dot(ac, bp)
        d5 = wp.dot(ab, cp)
        d6 = wp.dot(ac, cp)
        va = d3 * d6 - d5 * d4
        vb = d5 * d2 - d1 * d6
        vc = d1 * d4 - d3 * d2
        zero = f64(0.0)
        one = f64(1.0)
        # the interior, then each region in reverse priority order, so the first of Ericson's
        # tests that holds wins
        den = va + vb + vc
        v_in = ratio(vb, den)
        w_in = ratio(vc, den)
        bary = wp.vec3d(one - v_in - w_in, v_in, w_in)
        w_bc = ratio(d4 - d3, (d4 - d3) + (d5 - d6))
        bary = wp.where((va <= zero) and (d4 - d3 >= zero) and (d5 - d6 >= zero),
                        wp.vec3d(zero, one - w_bc, w_bc), bary)
        w_ac = ratio(d2, d2 - d6)
        bary = wp.where((vb <= zero) and (d2 >= zero) and (d6 <= zero), wp.vec3d(one - w_ac, zero, w_ac), bary)
        bary = wp.where((d6 >= zero) and (d5 <= d6), wp.vec3d(zero, zero, one), bary)
        v_ab = ratio(d1, d1 - d3)
        bary = wp.where((vc <= zero) and (d1 >= zero) and (d3 <= zero), wp.vec3d(one - v_ab, v_ab, zero), bary)
        bary = wp.where((d3 >= zero) and (d4 <= d3), wp.vec3d(zero, one, zero), bary)
        bary = wp.where((d1 <= zero) and (d2 <= zero), wp.vec3d(one, zero, zero), bary)
        return bary

    @wp.kernel
    def closest_kernel(points: wp.array(dtype=wp.vec3d), verts: wp.array(dtype=wp.vec3d),
                       corners: wp.array2d(dtype=wp.int32), closest: wp.array(dtype=wp.vec3d),
                       bary: wp.array(dtype=wp.vec3d)):
        i = wp.tid()
        a = verts[corners[i, 0]]
        b = verts[corners[i, 1]]
        c = verts[corners[i, 2]]
        w = closest_bary(points[i], a, b, c)
        bary[i] = w
        closest[i] = w[0] * a + w[1] * b + w[2] * c

    @wp.func
    def feature_normal(w: wp.vec3d, b: wp.int32, f: wp.int32, faces: wp.array2d(dtype=wp.int32),
                       face_normals: wp.array2d(dtype=wp.vec3d), edge_normals: wp.array3d(dtype=wp.vec3d),
                       vertex_normals: wp.array2d(dtype=wp.vec3d)):
        """The pseudo-normal of the feature of face f that barycentrics w lie on: no zero → the
        face's, one zero → the edge's opposite that corner, two zeros → the vertex's of the largest
        weight."""
        zero = f64(0.0)
        zeros = int(w[0] == zero) + int(w[1] == zero) + int(w[2] == zero)
        n = face_normals[b, f]
        if zeros == 1:  # on the edge opposite the zero corner
            k = 0
            if w[1] == zero:
                k = 1
            if w[2] == zero:
                k = 2
            n = edge_normals[b, f, k]
        if zeros >= 2:  # at the corner of the largest weight
            k = 0
            if w[1] > w[0]:
                k = 1
            if w[2] > w[k]:
                k = 2
            n = vertex_normals[b, faces[f, k]]
        return n

    @wp.func
    def surface_point(x: wp.vec3d, verts: wp.array(dtype=wp.vec3d), b: wp.int32, f: wp.int32, num_verts: wp.int32,
                      faces: wp.array2d(dtype=wp.int32), face_normals: wp.array2d(dtype=wp.vec3d),
                      edge_normals: wp.array3d(dtype=wp.vec3d), vertex_normals: wp.array2d(dtype=wp.vec3d),
                      near_tol: wp.float64):
        """Point x against face f of body b: the closest point p, its barycentrics, the normal
        (x − p)/|x − p| signed by the pseudo-normal of the feature p lies on, or that pseudo-normal
        within near_tol, the signed distance (x − p)·normal, and flags (1: inside by the
        pseudo-normal's sign, 2: within near_tol)."""
        row = b * num_verts
        a = verts[row + faces[f, 0]]
        bb = verts[row + faces[f, 1]]
        c = verts[row + faces[f, 2]]
        w = closest_bary(x, a, bb, c)
        p = w[0] * a + w[1] * bb + w[2] * c
        pseudo = feature_normal(w, b, f, faces, face_normals, edge_normals, vertex_normals)
        r = x - p
        dist = wp.length(r)
        inside = wp.dot(r, pseudo) < f64(0.0)
        near = dist <= near_tol
        sign = wp.where(inside, f64(-1.0), f64(1.0))
        n = wp.where(near, pseudo, (sign * ratio(f64(1.0), dist)) * r)
        return p, w, n, wp.dot(r, n), wp.where(inside, 1, 0) + wp.where(near, 2, 0)

    @wp.kernel
    def surface_kernel(points: wp.array(dtype=wp.vec3d), verts: wp.array(dtype=wp.vec3d),
                       body: wp.array(dtype=wp.int32), face: wp.array(dtype=wp.int32), num_verts: wp.int32,
                       faces: wp.array2d(dtype=wp.int32), face_normals: wp.array2d(dtype=wp.vec3d),
                       edge_normals: wp.array3d(dtype=wp.vec3d), vertex_normals: wp.array2d(dtype=wp.vec3d),
                       near_tol: wp.float64, closest: wp.array(dtype=wp.vec3d), bary: wp.array(dtype=wp.vec3d),
                       normal: wp.array(dtype=wp.vec3d), distance: wp.array(dtype=wp.float64),
                       flags: wp.array(dtype=wp.int32)):
        i = wp.tid()
        p, w, n, d, flag = surface_point(points[i], verts, body[i], face[i], num_verts, faces, face_normals,
                                         edge_normals, vertex_normals, near_tol)
        closest[i] = p
        bary[i] = w
        normal[i] = n
        distance[i] = d
        flags[i] = flag

    @wp.func
    def distance_sq(x: wp.vec3d, verts: wp.array(dtype=wp.vec3d), row: wp.int32, faces: wp.array2d(dtype=wp.int32),
                    f: wp.int32):
        a = verts[row + faces[f, 0]]
        b = verts[row + faces[f, 1]]
        c = verts[row + faces[f, 2]]
        w = closest_bary(x, a, b, c)
        r = x - (w[0] * a + w[1] * b + w[2] * c)
        return wp.dot(r, r)

    @wp.func
    def walk(x: wp.vec3d, verts: wp.array(dtype=wp.vec3d), row: wp.int32, faces: wp.array2d(dtype=wp.int32),
             rings: wp.array2d(dtype=wp.int32), start: wp.int32, max_moves: wp.int32):
        """The closest triangle to x found by walking from `start` over the rings (of the body
        whose vertices start at `row`): `walk_to_closest_faces`."""
        best = start
        best_d = distance_sq(x, verts, row, faces, best)
        for _move in range(max_moves):
            centre = best
            for j in range(rings.shape[1]):
                g = rings[centre, j]
                if g < faces.shape[0]:  # the table's padding is the face count
                    d = distance_sq(x, verts, row, faces, g)
                    if d < best_d:
                        best_d = d
                        best = g
            if best == centre:
                break
        return best

    @wp.kernel
    def walk_kernel(points: wp.array(dtype=wp.vec3d), verts: wp.array(dtype=wp.vec3d),
                    body: wp.array(dtype=wp.int32), start: wp.array(dtype=wp.int32), num_verts: wp.int32,
                    faces: wp.array2d(dtype=wp.int32), rings: wp.array2d(dtype=wp.int32), max_moves: wp.int32,
                    face: wp.array(dtype=wp.int32)):
        i = wp.tid()
        face[i] = walk(points[i], verts, body[i] * num_verts, faces, rings, start[i], max_moves)

    return {"wp": wp, "closest": closest_kernel, "surface": surface_kernel, "walk": walk_kernel,
            "surface_point": surface_point, "walk_func": walk}


def _vec3(wp, t: Tensor):
    return launch_arg(t, wp.vec3d)


def _int2d(wp, t: Tensor):
    return launch_arg(t, wp.int32)


class _ClosestPoint(torch.autograd.Function):
    """(closest, bary) = kernel(points, verts, corners) with the kernel's adjoint as the backward.

    points (M, 3) and verts (N, 3) float64 contiguous; corners (M, 3) int32: the rows of verts
    that are each point's triangle."""

    @staticmethod
    def forward(ctx, points: Tensor, verts: Tensor, corners: Tensor) -> tuple[Tensor, Tensor]:
        wp = kernels()["wp"]
        closest, bary = torch.empty_like(points), torch.empty_like(points)
        if points.shape[0]:
            with torch_stream(points.device):
                wp.launch(kernels()["closest"], dim=points.shape[0], device=wp.device_from_torch(points.device),
                          inputs=[_vec3(wp, points), _vec3(wp, verts), _int2d(wp, corners)],
                          outputs=[_vec3(wp, closest), _vec3(wp, bary)])
        ctx.save_for_backward(points, verts, corners)
        return closest, bary

    @staticmethod
    def backward(ctx, grad_closest: Tensor, grad_bary: Tensor):
        if torch.is_grad_enabled():  # a graph of this backward (create_graph=True) would miss the inputs
            raise RuntimeError("the closest point is differentiable once: its backward cannot be "
                               "differentiated again (create_graph=True, torch.func.hessian)")
        points, verts, corners = ctx.saved_tensors
        wp = kernels()["wp"]
        grad_points, grad_verts = torch.zeros_like(points), torch.zeros_like(verts)
        grads = [torch.zeros_like(points) if g is None else g.to(torch.float64).contiguous()
                 for g in (grad_closest, grad_bary)]
        if points.shape[0]:
            with torch_stream(points.device):
                wp.launch(kernels()["closest"], dim=points.shape[0], device=wp.device_from_torch(points.device),
                          inputs=[_vec3(wp, points), _vec3(wp, verts), _int2d(wp, corners)],
                          outputs=[_vec3(wp, torch.empty_like(points)), _vec3(wp, torch.empty_like(points))],
                          adj_inputs=[_vec3(wp, grad_points), _vec3(wp, grad_verts), _int2d(wp, corners)],
                          adj_outputs=[_vec3(wp, grads[0]), _vec3(wp, grads[1])], adjoint=True)
        return grad_points, grad_verts, None


def closest_point_on_indexed_triangles(points: Tensor, verts: Tensor, corners: Tensor) -> tuple[Tensor, Tensor]:
    """Exact closest point of each point on its triangle, the triangles given as rows of a vertex
    table.

    Args:
        points: query points [m], shape (M, 3).
        verts: vertex positions [m], shape (N, 3), same dtype as points.
        corners: each point's triangle as three row indices into verts, shape (M, 3) int.

    Returns:
        p: closest points [m], shape (M, 3), in points' dtype, differentiable w.r.t. points and
            verts.
        bary: barycentric coordinates (wa, wb, wc) of p, shape (M, 3); a coordinate is exactly
            zero when p lies on the opposite edge (two are zero at a vertex).
    """
    if points.dtype != verts.dtype:
        raise TypeError(f"points are {points.dtype} but verts are {verts.dtype}; convert one of them explicitly")
    p, bary = _ClosestPoint.apply(points.to(torch.float64).contiguous(), verts.to(torch.float64).contiguous(),
                                  corners.to(torch.int32).contiguous())
    return p.to(points.dtype), bary.to(points.dtype)


def closest_point_on_triangle(x: Tensor, a: Tensor, b: Tensor, c: Tensor) -> tuple[Tensor, Tensor]:
    """Exact closest point on triangles (Ericson, Real-Time Collision Detection, Sec. 5.1.5).

    Args:
        x: query points [m], shape (..., 3).
        a, b, c: triangle corners [m], shape (..., 3) (broadcast against x).

    Returns:
        p: closest points [m], shape (..., 3), differentiable w.r.t. x, a, b, c.
        bary: barycentric coordinates (wa, wb, wc) of p, shape (..., 3); a coordinate is exactly
            zero when p lies on the opposite edge (two are zero at a vertex).
    """
    x, a, b, c = torch.broadcast_tensors(x, a, b, c)
    lead = x.shape[:-1]
    num = x[..., 0].numel()
    corners = torch.arange(3 * num, device=x.device).reshape(3, num).T
    verts = torch.cat([a.reshape(num, 3), b.reshape(num, 3), c.reshape(num, 3)])
    p, bary = closest_point_on_indexed_triangles(x.reshape(num, 3), verts, corners)
    return p.reshape(*lead, 3), bary.reshape(*lead, 3)


@dataclass(frozen=True)
class SurfaceArrays:
    """Bodies' surfaces as the walk and the closest-point kernels read them (float64, int32,
    contiguous; `BodySurface.walk_arrays`): the vertices flattened (B · N, 3), the triangles
    (F, 3), each triangle's ring (F, W) padded with F, the face (B, F, 3), edge (B, F, 3, 3) and
    vertex (B, N, 3) pseudo-normals, N, and the distance [m] within which a point counts as on
    the surface (`closest_surface_points`)."""

    verts: Tensor
    faces: Tensor
    rings: Tensor
    face_normals: Tensor
    edge_normals: Tensor
    vertex_normals: Tensor
    num_verts: int
    near_tol: float

    def launch_args(self, wp, max_moves: int) -> list:
        """The arrays as launch arguments, in the order the follow kernel takes them
        (`physics.contact_kernels`)."""
        return [_vec3(wp, self.verts), int(self.num_verts), _int2d(wp, self.faces), _int2d(wp, self.rings),
                int(max_moves), _vec3(wp, self.face_normals), _vec3(wp, self.edge_normals),
                _vec3(wp, self.vertex_normals), float(self.near_tol)]


@dataclass(frozen=True)
class SurfacePoints:
    """Closest points on indexed triangles with their normals (`closest_surface_points`); float64,
    leading shape (M,).

    Attributes:
        closest: the closest point p [m] (M, 3); bary: its barycentrics (M, 3).
        normal: (x − p) / |x − p| signed by the pseudo-normal, or the pseudo-normal itself within
            near_tol of the surface (M, 3).
        signed_distance: (x − p) · normal [m] (M,).
        inside: the pseudo-normal's sign, (x − p) · n_pseudo < 0 (M,) bool.
        near: |x − p| ≤ near_tol (M,) bool.
    """

    closest: Tensor
    bary: Tensor
    normal: Tensor
    signed_distance: Tensor
    inside: Tensor
    near: Tensor


class _SurfacePoints(torch.autograd.Function):
    """closest, bary, normal, signed distance = kernel(points, verts, …) with the kernel's adjoint
    as the backward (w.r.t. points and verts; the feature's pseudo-normal counts as a constant)."""

    @staticmethod
    def forward(ctx, points: Tensor, verts: Tensor, body: Tensor, face: Tensor, num_verts: int, faces: Tensor,
                normals: tuple[Tensor, Tensor, Tensor], near_tol: float):
        wp = kernels()["wp"]
        m = points.shape[0]
        closest, bary, normal = (torch.empty_like(points) for _ in range(3))
        distance = torch.empty(m, dtype=torch.float64, device=points.device)
        flags = torch.empty(m, dtype=torch.int32, device=points.device)
        if m:
            with torch_stream(points.device):
                wp.launch(kernels()["surface"], dim=m, device=wp.device_from_torch(points.device),
                          inputs=_surface_inputs(wp, points, verts, body, face, num_verts, faces, normals, near_tol),
                          outputs=[_vec3(wp, closest), _vec3(wp, bary), _vec3(wp, normal),
                                   launch_arg(distance, wp.float64), launch_arg(flags, wp.int32)])
        ctx.save_for_backward(points, verts, body, face, faces, *normals)
        ctx.num_verts, ctx.near_tol = num_verts, near_tol
        ctx.mark_non_differentiable(flags)
        return closest, bary, normal, distance, flags

    @staticmethod
    def backward(ctx, grad_closest, grad_bary, grad_normal, grad_distance, _grad_flags):
        if torch.is_grad_enabled():
            raise RuntimeError("the closest point is differentiable once: its backward cannot be "
                               "differentiated again (create_graph=True, torch.func.hessian)")
        points, verts, body, face, faces, *normals = ctx.saved_tensors
        wp = kernels()["wp"]
        grad_points = torch.zeros_like(points)
        # the bodies' vertices get an adjoint only when asked: a batch of many bodies (a training
        # pool) would otherwise fill one of all their vertices at every backward
        grad_verts = torch.zeros_like(verts) if ctx.needs_input_grad[1] else None
        grads = [torch.zeros_like(points) if g is None else g.to(torch.float64).contiguous()
                 for g in (grad_closest, grad_bary, grad_normal)]
        grad_distance = (torch.zeros(points.shape[0], dtype=torch.float64, device=points.device)
                         if grad_distance is None else grad_distance.to(torch.float64).contiguous())
        flags = torch.empty(points.shape[0], dtype=torch.int32, device=points.device)
        if points.shape[0]:
            with torch_stream(points.device):
                inputs = _surface_inputs(wp, points, verts, body, face, ctx.num_verts, faces, normals, ctx.near_tol)
                # a null adjoint array (None) is skipped by the kernel's adjoint: the pseudo-normals'
                # adjoints are not wanted (they count as constants), nor the vertices' unless asked
                adj_inputs = _surface_inputs(wp, grad_points, grad_verts, body, face, ctx.num_verts, faces,
                                             (None, None, None), ctx.near_tol)
                wp.launch(kernels()["surface"], dim=points.shape[0], device=wp.device_from_torch(points.device),
                          inputs=inputs, outputs=[*(_vec3(wp, torch.empty_like(points)) for _ in range(3)),
                                                  launch_arg(torch.empty_like(grad_distance), wp.float64),
                                                  launch_arg(flags, wp.int32)],
                          adj_inputs=adj_inputs,
                          adj_outputs=[*(_vec3(wp, g) for g in grads), launch_arg(grad_distance, wp.float64),
                                       launch_arg(flags, wp.int32)], adjoint=True)
        return grad_points, grad_verts, None, None, None, None, None, None


def _surface_inputs(wp, points, verts, body, face, num_verts, faces, normals, near_tol) -> list:
    """The surface kernel's inputs in its order; a None array passes a null array."""
    def vec3(t: Tensor | None):
        return None if t is None else _vec3(wp, t)

    face_normals, edge_normals, vertex_normals = normals
    return [vec3(points), vec3(verts), launch_arg(body, wp.int32), launch_arg(face, wp.int32),
            int(num_verts), _int2d(wp, faces), vec3(face_normals), vec3(edge_normals), vec3(vertex_normals),
            float(near_tol)]


def closest_surface_points(points: Tensor, verts: Tensor, body: Tensor, face: Tensor, faces: Tensor,
                           face_normals: Tensor, edge_normals: Tensor, vertex_normals: Tensor, *,
                           near_tol: float) -> SurfacePoints:
    """The closest point of each point on its triangle of its body, and the normal and signed
    distance there, in one kernel launch: what a body-surface query computes once its BVH has
    found the triangles (`geometry.proximity`).

    Args:
        points: query points [m], (M, 3) float64 contiguous.
        verts: the bodies' vertices flattened, (B · N, 3) float64 contiguous (body b's vertex j at
            row b · N + j).
        body, face: each point's body and triangle (a row of `faces`), (M,) int32 contiguous.
        faces: the bodies' triangles, (F, 3) int32 contiguous.
        face_normals: (B, F, 3); edge_normals: (B, F, 3, 3), face f's edge opposite its corner k
            at [:, f, k]; vertex_normals: (B, N, 3); unit angle-weighted pseudo-normals, float64
            contiguous.
        near_tol: distance [m] within which a point counts as on the surface and its normal is
            the pseudo-normal of the feature its closest point lies on (the face's, an edge's or a
            vertex's, read off the barycentrics' exact zeros).

    Returns:
        `SurfacePoints`; closest, bary, normal and signed_distance differentiable w.r.t. points
        and verts (once).
    """
    closest, bary, normal, distance, flags = _SurfacePoints.apply(
        points, verts, body, face, vertex_normals.shape[1], faces, (face_normals, edge_normals, vertex_normals),
        near_tol)
    return SurfacePoints(closest, bary, normal, distance, (flags & 1).bool(), (flags & 2).bool())


def walk_to_closest_faces(points: Tensor, verts: Tensor, body: Tensor, start: Tensor, faces: Tensor,
                          rings: Tensor, *, num_verts: int, max_moves: int = WALK_MOVES) -> Tensor:
    """The closest triangle of each point near a triangle it starts from: the start and its ring
    (the triangles that share a vertex with it) are tested, the closest becomes the next start,
    until the start stays (or after `max_moves` moves). A local search, in one launch: it ends on
    a triangle at least as close as the start, the closest of the surface wherever that lies
    within the rings it walks through (a point that has moved a fraction of an edge length since
    its start was its closest triangle), and can stop short of a closer sheet farther along the
    surface (another limb), which only a search of the whole surface finds.

    Args:
        points: (M, 3) float64 contiguous [m]; verts: the bodies' vertices flattened (B · N, 3)
            float64 contiguous (N = num_verts); body, start: each point's body and starting
            triangle (M,) int32 contiguous; faces: (F, 3) int32 contiguous.
        rings: each triangle's ring, (F, W) int32 contiguous, padded with F
            (`geometry.topology.face_rings`).

    Returns:
        face: (M,) int32; of equally close triangles the first found (deterministic).
    """
    wp = kernels()["wp"]
    face = torch.empty(points.shape[0], dtype=torch.int32, device=points.device)
    if points.shape[0]:
        with torch_stream(points.device):
            wp.launch(kernels()["walk"], dim=points.shape[0], device=wp.device_from_torch(points.device),
                      inputs=[_vec3(wp, points), _vec3(wp, verts), launch_arg(body, wp.int32),
                              launch_arg(start, wp.int32), int(num_verts), _int2d(wp, faces), _int2d(wp, rings),
                              int(max_moves)],
                      outputs=[launch_arg(face, wp.int32)])
    return face

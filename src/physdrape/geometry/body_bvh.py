"""The search half of the body-surface queries: NVIDIA Warp triangle-mesh BVHs, one per body.

`BodyBVH` holds one ``wp.Mesh`` per body of a batch sharing one topology (built once, ``refit()``
when only the vertex positions change) and finds the closest triangle of every query point in
float32 and, if asked, the generalized winding number (Warp's fast winding number, Barill et al.
2018) for the inside test. Nothing here is differentiated: `geometry.proximity` recomputes the
closest point on the found triangle in torch.

The Warp kernels are defined lazily, once per process (Warp caches the compiled binary on disk).
The BVHs live on the device of the body vertices (CPU or CUDA); the query tensors are shared with
Warp without copies (`wp.from_torch`) and the kernels launch on that device. On CUDA every Warp
operation runs on torch's current stream of the device, so it is ordered with the torch ops that
write its inputs and read its outputs.
"""

from __future__ import annotations

import collections
import itertools

import numpy as np
import torch
from torch import Tensor

from physdrape.threads import parallel_map, run_parts
from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

__all__ = ["BodyBVH"]

#: Below this many points per thread the search runs on one thread (launch overhead dominates).
_MIN_POINTS_PER_THREAD = 1024
#: Query sizes whose last points and closest faces a BVH keeps for reuse (`closest_faces`).
_RECENT_QUERIES = 4


@defined_once
def _query_kernels():
    """Import warp and define the query kernels (first call only)."""
    wp = warp()

    @wp.kernel(enable_backward=False)
    def closest_kernel(
        mesh_ids: wp.array(dtype=wp.uint64),
        body: wp.array(dtype=wp.int32),
        points: wp.array(dtype=wp.vec3),
        max_dist: float,
        face: wp.array(dtype=wp.int32),
    ):
        i = wp.tid()
        q = wp.mesh_query_point_no_sign(mesh_ids[body[i]], points[i], max_dist)
        if q.result:
            face[i] = q.face
        else:
            face[i] = -1

    @wp.kernel(enable_backward=False)
    def closest_winding_kernel(
        mesh_ids: wp.array(dtype=wp.uint64),
        body: wp.array(dtype=wp.int32),
        points: wp.array(dtype=wp.vec3),
        max_dist: float,
        accuracy: float,
        face: wp.array(dtype=wp.int32),
        inside: wp.array(dtype=wp.int32),
    ):
        i = wp.tid()
        q = wp.mesh_query_point_sign_winding_number(mesh_ids[body[i]], points[i], max_dist, accuracy, 0.5)
        if q.result:
            face[i] = q.face
            inside[i] = wp.where(q.sign < 0.0, 1, 0)
        else:
            face[i] = -1
            inside[i] = 0

    @wp.kernel(enable_backward=False)
    def ray_kernel(
        mesh_ids: wp.array(dtype=wp.uint64),
        body: wp.array(dtype=wp.int32),
        points: wp.array(dtype=wp.vec3),
        directions: wp.array(dtype=wp.vec3),
        hit: wp.array(dtype=wp.int32),
        facing: wp.array(dtype=wp.float32),
    ):
        i = wp.tid()
        d = directions[i]
        q = wp.mesh_query_ray(mesh_ids[body[i]], points[i], d, 1.0e30)
        hit[i] = wp.where(q.result, 1, 0)
        facing[i] = 0.0
        if q.result:
            facing[i] = wp.dot(wp.normalize(q.normal), d) / wp.max(wp.length(d), 1.0e-30)

    return wp, closest_kernel, closest_winding_kernel, ray_kernel


class BodyBVH:
    """One Warp BVH per body of a batch sharing one triangle topology.

    Args:
        verts: body vertex positions [m], shape (B, Vb, 3); copied to float32 (Warp meshes are
            float32).
        faces: triangles, shape (Fb, 3) int64, on the device of ``verts``.
        with_winding_number: also build the winding-number data the inside test needs.
    """

    def __init__(self, verts: Tensor, faces: Tensor, *, with_winding_number: bool) -> None:
        wp = _query_kernels()[0]
        self.with_winding_number = with_winding_number
        self._device = verts.device
        self._wp_device = wp.device_from_torch(verts.device)
        # float32 copies the BVHs point at; must outlive the meshes.
        self._points32 = verts.detach().to(torch.float32).contiguous().clone()
        self._indices32 = faces.to(device=verts.device, dtype=torch.int32).reshape(-1).contiguous()
        with torch_stream(self._device):
            wp_indices = wp.from_torch(self._indices32, dtype=wp.int32)

            def build(b: int):
                return wp.Mesh(points=wp.from_torch(self._points32[b], dtype=wp.vec3), indices=wp_indices,
                               support_winding_number=with_winding_number)

            bodies = list(range(verts.shape[0]))
            if self._wp_device.is_cpu and torch.get_num_threads() > 1:  # the bodies' BVHs on parallel threads
                self._meshes = parallel_map(build, bodies, "bvh", torch.get_num_threads())
            else:
                self._meshes = [build(b) for b in bodies]
            ids = np.array([m.id for m in self._meshes], dtype=np.uint64)
            self._mesh_ids = wp.array(ids, dtype=wp.uint64, device=self._wp_device)
        self._recent: collections.OrderedDict[int, tuple[Tensor, Tensor, Tensor]] = collections.OrderedDict()

    def select(self, index: int) -> BodyBVH:
        """Body `index` alone, sharing this batch's BVH (no copy, no build). A refit of either moves
        both; the selection keeps this batch alive."""
        wp = _query_kernels()[0]
        one = object.__new__(BodyBVH)
        one.with_winding_number = self.with_winding_number
        one._device, one._wp_device = self._device, self._wp_device
        one._points32 = self._points32[index:index + 1]
        one._indices32 = self._indices32
        one._meshes = [self._meshes[index]]
        one._parent = self
        one._mesh_ids = wp.array(np.array([self._meshes[index].id], dtype=np.uint64), dtype=wp.uint64,
                                 device=self._wp_device)
        one._recent = collections.OrderedDict()
        return one

    def refit(self, verts: Tensor) -> None:
        """Move the bodies to new vertex positions of the same shape (B, Vb, 3): refit, no rebuild."""
        self._points32.copy_(verts.detach())
        self._recent.clear()
        with torch_stream(self._device):
            for mesh in self._meshes:
                mesh.refit()

    def forget_recent(self) -> None:
        """Drop the searches kept for reuse: the next reusing search of each size searches every point."""
        self._recent.clear()

    def _reusing(self, points32: Tensor, body: Tensor, **search) -> Tensor:
        """`closest_faces(..., reuse=True)`'s faces (see there)."""
        last = self._recent.get(points32.shape[0])
        if last is None:
            face = self.closest_faces(points32, body, winding=False, **search)[0]
        else:
            old_points, old_body, face = last
            moved = torch.nonzero((points32 != old_points).any(-1) | (body != old_body))[:, 0]
            if moved.numel():
                face = face.clone()
                face[moved] = self.closest_faces(points32[moved].contiguous(), body[moved].contiguous(),
                                                 winding=False, **search)[0]
        self._recent[points32.shape[0]] = (points32.clone(), body.clone(), face)
        self._recent.move_to_end(points32.shape[0])
        while len(self._recent) > _RECENT_QUERIES:
            self._recent.popitem(last=False)
        return face.clone()

    def ray_hits(self, points32: Tensor, body: Tensor, directions32: Tensor, *,
                 threads: int | None = None) -> tuple[Tensor, Tensor]:
        """Whether the ray from each point along its direction hits its body's surface, shape (M,)
        bool, and the cosine of the angle between the ray and the outward normal of the first
        face it hits (M,) float32 (< 0: the ray enters the surface there; 0 where it hits
        nothing); points32, directions32 (M, 3) float32 and body (M,) int32, contiguous, on the
        bodies' device (split between CPU threads like `closest_faces`)."""
        wp, _, _, ray_kernel = _query_kernels()
        hit = torch.empty(points32.shape[0], dtype=torch.int32, device=points32.device)
        facing = torch.empty(points32.shape[0], dtype=torch.float32, device=points32.device)

        def launch(lo: int, hi: int) -> None:
            wp.launch(ray_kernel, dim=hi - lo, device=self._wp_device,
                      inputs=[self._mesh_ids, launch_arg(body[lo:hi], wp.int32),
                              launch_arg(points32[lo:hi], wp.vec3),
                              launch_arg(directions32[lo:hi], wp.vec3)],
                      outputs=[launch_arg(hit[lo:hi], wp.int32), launch_arg(facing[lo:hi], wp.float32)])

        self._run_chunks(launch, points32.shape[0], threads)
        return hit.bool(), facing

    def _run_chunks(self, launch, n: int, threads: int | None) -> None:
        """launch(lo, hi) over n points: in chunks on parallel CPU threads when there are enough
        points (Warp releases the GIL inside a kernel; bit-for-bit the result of one launch)."""
        threads = threads or torch.get_num_threads()
        chunks = min(threads, n // _MIN_POINTS_PER_THREAD) if self._wp_device.is_cpu else 1
        if chunks > 1:
            bounds = np.linspace(0, n, chunks + 1).astype(int).tolist()
            run_parts(launch, list(itertools.pairwise(bounds)), "bvh")
        elif n:
            with torch_stream(self._device):
                launch(0, n)

    def closest_faces(
        self, points32: Tensor, body: Tensor, *, winding_accuracy: float, threads: int | None = None,
        winding: bool | None = None, reuse: bool = False,
    ) -> tuple[Tensor, Tensor | None]:
        """Closest face (and winding-number inside flag) per point.

        Args:
            points32: query points [m], shape (M, 3) float32, contiguous, on the bodies' device.
            body: which body each point belongs to, shape (M,) int32, contiguous, on that device.
            winding_accuracy: Warp's fast-winding-number accuracy (see `BodySurface`).
            threads: CPU threads that share the search (the points are split into chunks launched
                from a thread pool, bit-for-bit the same result). None = `torch.get_num_threads()`.
            winding: also evaluate the winding number (needs `with_winding_number`); None = when
                the BVHs were built with it.
            reuse: search only the points that differ (bitwise, or in their body) from the same
                row of the last reusing search of as many points, and keep the others' faces from
                it (the search is deterministic: the same faces as a full search). For callers
                that ask again about points most of which have not moved (the collision handler's
                second pass, the metrics, the strain limiter's sweeps); not with `winding`.

        Returns:
            face: shape (M,) int64; inside: shape (M,) bool, or None without the winding number.
        """
        if reuse:
            if winding:
                raise ValueError("closest_faces(reuse=True) keeps closest faces only, not winding numbers")
            return self._reusing(points32, body, winding_accuracy=winding_accuracy, threads=threads), None
        wp, closest_kernel, closest_winding_kernel, _ = _query_kernels()
        n = points32.shape[0]
        face = torch.empty(n, dtype=torch.int32, device=points32.device)
        with_wn = self.with_winding_number if winding is None else winding
        if with_wn and not self.with_winding_number:
            raise ValueError("closest_faces(winding=True) needs BVHs built with_winding_number=True")
        inside = torch.empty(n, dtype=torch.int32, device=points32.device) if with_wn else None
        max_dist = 1.0e30

        def launch(lo: int, hi: int) -> None:
            points = launch_arg(points32[lo:hi], wp.vec3)
            owner = launch_arg(body[lo:hi], wp.int32)
            out_face = launch_arg(face[lo:hi], wp.int32)
            if with_wn:
                wp.launch(closest_winding_kernel, dim=hi - lo, device=self._wp_device,
                          inputs=[self._mesh_ids, owner, points, max_dist, winding_accuracy],
                          outputs=[out_face, launch_arg(inside[lo:hi], wp.int32)])
            else:
                wp.launch(closest_kernel, dim=hi - lo, device=self._wp_device,
                          inputs=[self._mesh_ids, owner, points, max_dist], outputs=[out_face])

        self._run_chunks(launch, n, threads)
        if n and int(face.min()) < 0:
            raise RuntimeError("the body BVH found no triangle for some points: every face of the body is "
                               "degenerate (zero area); check the body faces")
        return face.to(torch.int64), (inside.bool() if inside is not None else None)

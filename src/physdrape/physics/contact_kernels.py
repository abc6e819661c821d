"""The body-contact penalty on held closest-point planes, as NVIDIA Warp kernels (`physics.contact`
exposes them).

A solver step evaluates the contact at every sample (vertices, then face centroids) several times:
its distance to its plane for the energy, its force and its Gauss–Newton block. As chains of torch
ops (gathers for the centroids, outer products, index_add with repeated rows) each costs several
times the arithmetic; here each is one launch with one thread per sample, summing into the
vertices atomically, on the CPU or on CUDA. The energy k_c ReLU(ε − d)³ of the distances is
`contact.contact_energy` in torch (what the training loss differentiates) and `penalty` here (the
solver's line-search potential, `physics.potential`, checked against the torch one in its tests).
The follow kernel finds the planes of the samples near the body again by a walk over the body's
triangles from their last ones (`contact.follow_planes`), with the geometry kernels' functions
(`geometry.closest_point`).

A sample is given by its row of the corner table (`contact.sample_corners`): a vertex sample
repeats its vertex three times, a centroid sample names its face's corners. Its point is the
vertex, or (x_a + x_b + x_c) / 3 summed in that order (as `contact.contact_samples` forms it);
its distance to its plane (p, n) is d = (s − p)·n, and a centroid's force and blocks are shared
equally by its corners (∂s/∂x_a = I/3).
"""

# No `from __future__ import annotations` here: Warp reads the kernels' annotations as objects.
from typing import Any

from physdrape.geometry import closest_point
from physdrape.warp_runtime import defined_once, warp


@defined_once
def kernels() -> dict:
    """Define the kernels (first call only; Warp caches the compiled code on disk)."""
    wp = warp()
    f64 = wp.float64

    @wp.func
    def sample_point(x: wp.array2d(dtype=wp.vec3d), corners: wp.array2d(dtype=wp.int32), b: int, s: int):
        """Sample s of batch row b: its vertex, or its face's centroid."""
        a = corners[s, 0]
        centroid = (x[b, a] + x[b, corners[s, 1]] + x[b, corners[s, 2]]) / f64(3.0)
        return wp.where(a == corners[s, 1], x[b, a], centroid)

    @wp.func
    def plane_distance(x: wp.array2d(dtype=wp.vec3d), corners: wp.array2d(dtype=wp.int32),
                       closest: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d), b: int, s: int):
        """d = (s − p)·n of sample s of batch row b."""
        return wp.dot(sample_point(x, corners, b, s) - closest[s], normal[s])

    @wp.func
    def penalty(d: wp.float64, stiffness: wp.float64, margin: wp.float64):
        """k_c ReLU(ε − d)³ (`contact.contact_energy`)."""
        depth = wp.max(margin - d, f64(0.0))
        return stiffness * depth * depth * depth

    @wp.kernel
    def distance_kernel(x: wp.array2d(dtype=wp.vec3d), corners: wp.array2d(dtype=wp.int32),
                        closest: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d),
                        out: wp.array2d(dtype=wp.float64)):
        b, s = wp.tid()
        out[b, s] = plane_distance(x, corners, closest, normal, b, s)

    @wp.func
    def sample_force(d: wp.float64, n: wp.vec3d, stiffness: wp.float64, margin: wp.float64):
        """−∂/∂s of k_c ReLU(ε − d)³ at a sample at distance d from its plane of normal n:
        3 k_c ReLU(ε − d)² n."""
        depth = wp.max(margin - d, f64(0.0))
        return (f64(3.0) * stiffness * depth * depth) * n

    @wp.func
    def sample_block(d: wp.float64, n: wp.vec3d, stiffness: wp.float64, margin: wp.float64, band: wp.float64):
        """The Gauss–Newton block 6 k_c ReLU(ε − d) n nᵀ of a sample, taken at depth ≥ ε within
        `band` of its plane (`contact.plane_contact_blocks`)."""
        if d < band:
            d = wp.min(d, f64(0.0))
        depth = wp.max(margin - d, f64(0.0))
        return (f64(6.0) * stiffness * depth) * wp.outer(n, n)

    @wp.func
    def spread(out: wp.array2d(dtype=Any), corners: wp.array2d(dtype=wp.int32), b: int, s: int, value: Any,
               centroid_share: wp.float64):
        """A sample's force or block onto its vertex, or value / centroid_share onto each corner of
        its face (a force's third, a block's ninth: ∂s/∂x_a = I/3)."""
        a = corners[s, 0]
        c = corners[s, 1]
        if a == c:
            wp.atomic_add(out, b, a, value)
        else:
            share = value / centroid_share
            wp.atomic_add(out, b, a, share)
            wp.atomic_add(out, b, c, share)
            wp.atomic_add(out, b, corners[s, 2], share)

    @wp.kernel
    def force_kernel(x: wp.array2d(dtype=wp.vec3d), corners: wp.array2d(dtype=wp.int32),
                     closest: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d), stiffness: wp.float64,
                     margin: wp.float64, out: wp.array2d(dtype=wp.vec3d)):
        """f = 3 k_c ReLU(ε − d)² n onto a vertex sample's vertex, a third of it onto each corner
        of a centroid sample."""
        b, s = wp.tid()
        d = plane_distance(x, corners, closest, normal, b, s)
        if d < margin:
            spread(out, corners, b, s, sample_force(d, normal[s], stiffness, margin), f64(3.0))

    @wp.kernel(enable_backward=False)
    def blocks_kernel(x: wp.array2d(dtype=wp.vec3d), corners: wp.array2d(dtype=wp.int32),
                      closest: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d), stiffness: wp.float64,
                      margin: wp.float64, band: wp.float64, out: wp.array2d(dtype=wp.mat33d)):
        """6 k_c ReLU(ε − d) n nᵀ onto a vertex sample's vertex, a ninth onto each corner of a
        centroid sample; a sample within `band` of its plane is taken at depth ≥ ε."""
        b, s = wp.tid()
        d = plane_distance(x, corners, closest, normal, b, s)
        if d < wp.max(band, margin):
            spread(out, corners, b, s, sample_block(d, normal[s], stiffness, margin, band), f64(9.0))

    geometry = closest_point.kernels()
    walk, surface_point = geometry["walk_func"], geometry["surface_point"]

    @wp.kernel(enable_backward=False)
    def follow_kernel(x: wp.array2d(dtype=wp.vec3d), corners: wp.array2d(dtype=wp.int32),
                      closest: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d),
                      face: wp.array(dtype=wp.int32), found_at: wp.array(dtype=wp.vec3d),
                      sample_body: wp.array(dtype=wp.int32), band: wp.float64, min_move: wp.float64,
                      stiffness: wp.float64, margin: wp.float64,
                      verts: wp.array(dtype=wp.vec3d), num_verts: wp.int32, faces: wp.array2d(dtype=wp.int32),
                      rings: wp.array2d(dtype=wp.int32), max_moves: wp.int32,
                      face_normals: wp.array2d(dtype=wp.vec3d), edge_normals: wp.array3d(dtype=wp.vec3d),
                      vertex_normals: wp.array2d(dtype=wp.vec3d), near_tol: wp.float64,
                      doubtful: wp.array2d(dtype=wp.int32), doubt_mode: int,
                      before: wp.array(dtype=wp.float64), change: wp.array(dtype=wp.float64),
                      followed: wp.array(dtype=wp.int32)):
        """A sample within `band` of its plane (and, with min_move > 0, moved farther than that
        since `found_at`) walks from its plane's body face to the closest one and takes the plane
        there, in place (the closest point and the normal by the pseudo-normal's sign, as
        `BodySurface.query` finds them before its winding-number check; `found_at` its position);
        `change` is its penalty on the new plane minus that on the old one. The others keep theirs
        (change 0, followed 0). `before`: each sample's distance to its old plane. A followed
        sample's flags: 2 inside by the pseudo-normal's sign, 4 on the surface, 8 where that sign
        is in doubt: at a face flagged in `doubtful` (doubt_mode 1), at any face (2), or never (0)."""
        s = wp.tid()
        point = sample_point(x, corners, 0, s)
        d_before = wp.dot(point - closest[s], normal[s])
        before[s] = d_before
        follow = d_before < band
        if min_move > f64(0.0):
            follow = follow and wp.length(point - found_at[s]) > min_move
        if follow:
            b = sample_body[s]
            f = walk(point, verts, b * num_verts, faces, rings, face[s], max_moves)
            p, _bary, n, d, flags = surface_point(point, verts, b, f, num_verts, faces, face_normals, edge_normals,
                                                  vertex_normals, near_tol)
            closest[s] = p
            normal[s] = n
            face[s] = f
            found_at[s] = point
            change[s] = penalty(d, stiffness, margin) - penalty(d_before, stiffness, margin)
            doubt = 0
            if doubt_mode == 2:
                doubt = 8
            elif doubt_mode == 1:  # noqa: SIM102  (nested: Warp evaluates both sides of an `and`)
                if doubtful[b, f] != 0:
                    doubt = 8
            followed[s] = 1 + 2 * flags + doubt
        else:
            change[s] = f64(0.0)
            followed[s] = 0

    return {"follow": follow_kernel, "distance": distance_kernel, "force": force_kernel, "blocks": blocks_kernel,
            "plane_distance": plane_distance, "penalty": penalty,
            "sample_force": sample_force, "sample_block": sample_block, "spread": spread}

"""Strain limiting of a deformed mesh: shorten over-stretched edges toward a bound (Provot 1995).

Linear blend skinning stretches a garment where the body's own skin stretches (armpits and
shoulders under raised arms, where the skin stretches severalfold), and StVK forces there reach
thousands of times a vertex's weight. A few Jacobi sweeps of edge projection bring every edge
back under ``max_stretch`` times its rest length, moving both ends of an edge equally along it
and averaging the corrections per vertex; edges within the bound are untouched, so the rest of
the drape keeps its skinned shape. Batched over leading dimensions; each sweep is two Warp
kernels (three with a body; CPU or CUDA, float64). Gradients pass straight through it: the
corrections it makes count as a fixed displacement (exact where nothing is over the bound;
X_init is the model's input, made without gradient).

With a body, each sweep also pushes vertices closer than ``margin`` back out to it along the
body normal (the closest-point planes are re-queried every few sweeps), so a tight bound can pull
a garment onto a larger body without pulling it into it: a garment skinned onto a taller or wider
body than it was made for is stretched by the body's own growth, which a static drape does not
need where the garment can ride up.
"""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.geometry.distance_bound import DistanceBound
from physdrape.geometry.proximity import BodySurface
from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

__all__ = ["limit_edge_stretch", "max_edge_stretch"]


def max_edge_stretch(x: Tensor, edges: Tensor, rest_lengths: Tensor) -> Tensor:
    """Largest length / rest length over the edges, shape ``x.shape[:-2]``."""
    length = (x[..., edges[:, 1], :] - x[..., edges[:, 0], :]).norm(dim=-1)
    return (length / rest_lengths).amax(dim=-1)


def limit_edge_stretch(
    x: Tensor,
    edges: Tensor,
    rest_lengths: Tensor,
    *,
    max_stretch: float = 1.5,
    min_stretch: float | None = None,
    iterations: int = 100,
    relaxation: float = 1.5,
    body: BodySurface | None = None,
    margin: float = 2e-3,
    requery_every: int = 10,
    reach: float = 1e-2,
    momentum: float = 0.0,
) -> Tensor:
    """Project edges longer than ``max_stretch * rest`` toward that bound.

    Args:
        x: vertex positions [m], shape (..., V, 3).
        edges: undirected edges, shape (E, 2) int64.
        rest_lengths: their rest lengths [m], shape (E,) or broadcastable (..., E), > 0.
        max_stretch: the bound on length / rest length (> 1).
        min_stretch: a lower bound on length / rest length (< 1), or None: edges shorter than it
            are pushed apart toward it the same way (compression that skinning leaves, where the
            skin folds under a bent joint), within the same sweeps and stopping rule.
        iterations: Jacobi sweeps at most (stops early once every edge is within 1 % of the bound
            and every vertex above its floor; each mesh of a batch on its own, as it would alone).
        relaxation: over-relaxation of the averaged corrections (1 = plain Jacobi; < 2).
        body: posed bodies to keep the vertices out of (one per leading index: x of shape
            (B, V, 3) with B bodies, or (V, 3) with one), or None for no contact; queried in its
            own dtype.
        margin: after each sweep, a vertex is pushed back out to this distance from the body [m],
            or to its starting signed distance if that was smaller (strain limiting never moves
            a vertex deeper into the margin or the body; resolving what was already there is the
            collision handler's job).
        requery_every: sweeps between closest-point queries (the planes are held in between).
        reach: at the queries after the first, only the vertices that may have come within this
            distance [m] of the body since their planes were found are queried again (a vertex
            found at distance d that has moved m since is at least d − m away,
            `geometry.distance_bound`); the others keep
            their planes, which push only at the floor, at most `margin` from the body: a loose
            garment's far parts are searched once.
        momentum: heavy-ball momentum of the sweeps, in [0, 1) (0 = plain Jacobi); the velocity
            is reset whenever the total excess length grows (adaptive restart).

    Returns:
        positions of the same shape; edges that were within the bound and far from stretched
        ones keep their lengths exactly.
    """
    if not max_stretch > 1.0:
        raise ValueError(f"max_stretch must be > 1, got {max_stretch}")
    if min_stretch is not None and not 0.0 < min_stretch < 1.0:
        raise ValueError(f"min_stretch must be in (0, 1) or None, got {min_stretch}")
    if not 0.0 < relaxation < 2.0:
        raise ValueError(f"relaxation must be in (0, 2), got {relaxation}")
    if edges.ndim != 2 or edges.shape[1] != 2 or rest_lengths.shape[-1:] != edges.shape[:1]:
        raise ValueError(f"edges must be (E, 2) and rest_lengths (..., E), got {tuple(edges.shape)} and "
                         f"{tuple(rest_lengths.shape)}")
    if requery_every < 1 or not reach >= 0.0:
        raise ValueError(f"need requery_every >= 1 and reach >= 0 [m], got {requery_every} and {reach}")
    if not 0.0 <= momentum < 1.0:
        raise ValueError(f"momentum must be in [0, 1), got {momentum}")
    # Work on the leading dimensions flattened into one (B·V, 3) mesh of B disjoint copies, in
    # float64 (edge lengths and plane depths at sub-micrometre precision), in Warp kernels
    # (`_kernels`): per sweep one over the edges and one over the vertices (and, with a body, the
    # depth check over the vertices).
    shape, num_verts = x.shape, x.shape[-2]
    flat = x.detach().reshape(-1, 3).to(torch.float64, copy=True).contiguous()  # never the caller's tensor
    copies = flat.shape[0] // num_verts
    offsets = (torch.arange(copies, device=x.device) * num_verts)[:, None]
    ends = torch.stack([(edges[:, 0][None] + offsets).reshape(-1), (edges[:, 1][None] + offsets).reshape(-1)], 1)
    bound = (max_stretch * rest_lengths.to(torch.float64)).expand(*shape[:-2], edges.shape[0]).reshape(-1).contiguous()
    lower = bound * (min_stretch / max_stretch) if min_stretch is not None else bound[:1]
    wp, edge_kernel, vertex_kernel, depth_kernel = _kernels()
    device = wp.device_from_torch(x.device)
    buffers = [torch.zeros_like(flat) for _ in range(3)]  # next positions, shift, velocity
    count = torch.zeros(flat.shape[0], dtype=torch.float64, device=x.device)
    # per copy: total excess, any edge over, any vertex under; a copy stops (its sweeps skip it)
    # where a mesh alone would have stopped, so each copy ends where it ends alone (on the CPU bit
    # for bit; CUDA's atomic sums round in no fixed order)
    stats = torch.zeros(copies, 3, dtype=torch.float64, device=x.device)
    active = torch.ones(copies, dtype=torch.int32, device=x.device)
    copy_of_edge = torch.arange(copies, dtype=torch.int32, device=x.device).repeat_interleave(edges.shape[0])
    copy_of_vertex = torch.arange(copies, dtype=torch.int32, device=x.device).repeat_interleave(num_verts)
    planes = torch.zeros(3, *flat.shape, dtype=torch.float64, device=x.device)  # closest, normal, (floor, 0, 0)
    w = {name: launch_arg(t, wp.vec3d) for name, t in
         (("x", flat), ("next", buffers[0]), ("shift", buffers[1]), ("velocity", buffers[2]),
          ("closest", planes[0]), ("normal", planes[1]), ("floor", planes[2]))}
    w_ends = launch_arg(ends.to(torch.int32).contiguous(), wp.int32)
    w_bound, w_count = launch_arg(bound, wp.float64), launch_arg(count, wp.float64)
    w_lower = launch_arg(lower, wp.float64)
    w_stats, w_active = launch_arg(stats, wp.float64), launch_arg(active, wp.int32)
    w_edge_copy, w_vertex_copy = launch_arg(copy_of_edge, wp.int32), launch_arg(copy_of_vertex, wp.int32)
    held, found, previous, live = False, None, [None] * copies, [True] * copies
    with torch_stream(x.device):
        # the sweeps' launches, recorded once (their arrays stay the same): a recorded launch
        # replays without packing its arguments again, which costs more than a small kernel's
        # work on the CPU and holds the GIL that parallel X_inits share; the depth check and the
        # sweep on held planes only with a body
        edge = wp.launch(edge_kernel, dim=ends.shape[0], device=device, record_cmd=True,
                         inputs=[w["x"], w_ends, w_bound, w_lower, int(min_stretch is not None), w_edge_copy,
                                 w_active, w["shift"], w_count, w_stats])
        depth = None if body is None else wp.launch(
            depth_kernel, dim=flat.shape[0], device=device, record_cmd=True,
            inputs=[w["x"], w["closest"], w["normal"], w["floor"], 1e-2 * margin, w_vertex_copy, w_active, w_stats])
        vertex = [wp.launch(vertex_kernel, dim=flat.shape[0], device=device, record_cmd=True,
                            inputs=[w["x"], w["shift"], w_count, w["velocity"], float(relaxation), float(momentum),
                                    w["closest"], w["normal"], w["floor"], planes_held, w_vertex_copy, w_active,
                                    w["next"]])
                  for planes_held in ((0,) if body is None else (0, 1))]
        for sweep in range(iterations):
            if body is not None and sweep % requery_every == 0:
                with torch.no_grad():  # in the body's dtype (the planes hold to its precision)
                    if not held:
                        rows = None
                        query = body.query(flat.reshape(shape).to(body.verts.dtype))
                    else:  # the vertices of live meshes that may have come within reach since their planes were found
                        rows = found.rows_below(flat, reach)
                        rows = rows[active[copy_of_vertex[rows]] != 0]
                        query = body.query(flat[rows].to(body.verts.dtype), body_index=copy_of_vertex[rows],
                                           bound=found.select(rows))  # the side of those that cannot have crossed
                if rows is None:
                    planes[0] = query.closest.reshape(-1, 3)
                    planes[1] = query.normal.reshape(-1, 3)
                    # never deeper than at the start, never into the margin
                    planes[2, :, 0] = query.signed_distance.reshape(-1).to(torch.float64).clamp_max(margin)
                    found = DistanceBound.of(flat, query.signed_distance.reshape(-1))
                else:
                    planes[0, rows] = query.closest.to(torch.float64)
                    planes[1, rows] = query.normal.to(torch.float64)
                    found = found.updated(rows, flat[rows], query.signed_distance)
                held = True
            stats.zero_()
            edge.launch()
            if held:
                depth.launch()
            restart = []
            for c, (total, over, under) in enumerate(stats.tolist()):
                if not live[c]:
                    continue
                if not under and not over:
                    live[c] = False  # done: its sweeps stop here
                    active[c] = 0
                    continue
                if previous[c] is not None and total > previous[c]:
                    restart.append(c)  # adaptive restart: the momentum overshot
                previous[c] = total
            if not any(live):
                break
            if restart:
                buffers[2].view(copies, num_verts, 3)[restart] = 0.0
            vertex[int(held)].launch()
            flat.copy_(buffers[0])
    out = flat.reshape(shape).to(x.dtype)
    # gradients pass straight through: the limiter's corrections count as a fixed displacement
    return x + (out - x).detach() if x.requires_grad else out


@defined_once
def _kernels():
    """The sweep's Warp kernels (defined on first use; Warp caches the binaries on disk).

    edge: each edge longer than its bound moves both ends half the excess along it (atomically
    summed per vertex, with the count of such edges); adds the excess to its copy's stats[c, 0]
    and flags stats[c, 1] when it is over 1 % of the bound; with a lower bound, an edge shorter
    than it likewise moves its ends half the deficit apart. vertex: the averaged shift times the
    relaxation, plus momentum times the last move; with held planes, back up to the floor along
    the plane's normal; the shift and count are cleared for the next sweep. depth: flags
    stats[c, 2] when a vertex is more than `tol` below its floor. Each skips the elements of the
    copies that are no longer active (a vertex of one keeps its position).
    """
    wp = warp()
    f64 = wp.float64

    @wp.kernel(enable_backward=False)
    def edge_kernel(x: wp.array(dtype=wp.vec3d), ends: wp.array2d(dtype=wp.int32), bound: wp.array(dtype=wp.float64),
                    lower: wp.array(dtype=wp.float64), with_lower: int, copy: wp.array(dtype=wp.int32),
                    active: wp.array(dtype=wp.int32), shift: wp.array(dtype=wp.vec3d),
                    count: wp.array(dtype=wp.float64), stats: wp.array2d(dtype=wp.float64)):
        e = wp.tid()
        c = copy[e]
        if active[c] == 0:
            return
        i = ends[e, 0]
        j = ends[e, 1]
        d = x[j] - x[i]
        length = wp.length(d)
        excess = length - bound[e]
        limit = bound[e]
        if with_lower != 0 and excess <= f64(0.0):
            excess = lower[e] - length  # a deficit: the ends move apart
            limit = lower[e]
            d = -d
        if excess > f64(0.0):
            half = (f64(0.5) * excess / wp.max(length, f64(1e-12))) * d
            wp.atomic_add(shift, i, half)
            wp.atomic_sub(shift, j, half)
            wp.atomic_add(count, i, f64(1.0))
            wp.atomic_add(count, j, f64(1.0))
            wp.atomic_add(stats, c, 0, excess)
            if excess > f64(1e-2) * limit:
                stats[c, 1] = f64(1.0)

    @wp.kernel(enable_backward=False)
    def vertex_kernel(x: wp.array(dtype=wp.vec3d), shift: wp.array(dtype=wp.vec3d), count: wp.array(dtype=wp.float64),
                      velocity: wp.array(dtype=wp.vec3d), relaxation: wp.float64, momentum: wp.float64,
                      closest: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d),
                      floor: wp.array(dtype=wp.vec3d), held: int, copy: wp.array(dtype=wp.int32),
                      active: wp.array(dtype=wp.int32), out: wp.array(dtype=wp.vec3d)):
        v = wp.tid()
        if active[copy[v]] == 0:
            out[v] = x[v]
            return
        moved = x[v] + relaxation * shift[v] / wp.max(count[v], f64(1.0)) + momentum * velocity[v]
        if held != 0:
            depth = floor[v][0] - wp.dot(moved - closest[v], normal[v])
            if depth > f64(0.0):
                moved = moved + depth * normal[v]
        velocity[v] = moved - x[v]
        out[v] = moved
        shift[v] = wp.vec3d(f64(0.0), f64(0.0), f64(0.0))
        count[v] = f64(0.0)

    @wp.kernel(enable_backward=False)
    def depth_kernel(x: wp.array(dtype=wp.vec3d), closest: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d),
                     floor: wp.array(dtype=wp.vec3d), tol: wp.float64, copy: wp.array(dtype=wp.int32),
                     active: wp.array(dtype=wp.int32), stats: wp.array2d(dtype=wp.float64)):
        v = wp.tid()
        c = copy[v]
        if active[c] != 0 and floor[v][0] - wp.dot(x[v] - closest[v], normal[v]) > tol:
            stats[c, 2] = f64(1.0)

    return wp, edge_kernel, vertex_kernel, depth_kernel

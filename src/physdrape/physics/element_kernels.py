"""Per-element energies and forces of the garment's membrane (StVK) and bending terms, as NVIDIA
Warp kernels: the one implementation that `physics.strain` and `physics.bending` expose.

Every solver step evaluates these energies two or three times (the line search) and the forces
once. Written as chains of small torch ops (gathers, stacks, crosses, index_add), each of a few
thousand elements, they cost more in per-op overhead than in arithmetic. Here each is one kernel
launch with one thread per face or hinge, summing the forces into the vertices atomically, on the
CPU (compiled native code) or on CUDA, wherever the tensors live. On a CPU with several torch
threads a packed batch's launch is split between its garments, whose vertices are disjoint, and
the parts run on parallel threads (`physdrape.threads`).

The launch machinery (`run_kernel`) also serves the body contact's kernels on held planes
(`physics.contact_kernels`).

Differentiation: each kernel is wrapped in a `torch.autograd.Function` whose backward is the
kernel's adjoint, which Warp generates from the same source. So the energies' gradient is the
exact gradient of the energies, and the forces' backward is the exact Hessian–vector product
(what training needs: the solver's steps are differentiated through the forces). Only x is
differentiated; the cloth's coefficients are constants (an error says so if one asks for their
gradient). Double backward is not supported.

Numerics: the kernels compute in float64 whatever x's dtype (converting x in and the result out:
a few thousand elements), so a float32 garment gets float32 results of float64 arithmetic. Inputs
may carry leading batch dimensions, x (..., V, 3); the kernels launch over (batch, element).
"""

# No `from __future__ import annotations` here: Warp reads the kernels' annotations as objects, and
# a function that names `wp` only in its annotations cannot resolve them from a string.
import collections
import math
import threading
import weakref

import torch
from torch import Tensor

from physdrape.tensor_memo import TensorMemo
from physdrape.threads import disjoint_parts, run_parts
from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

__all__ = ["bend_energy_per_hinge", "bend_force", "hinge_angles", "run_kernel", "strain_energy_per_face", "strain_force"]


@defined_once
def _kernels() -> dict:
    """Define the kernels (first call only; Warp caches the compiled code on disk)."""
    wp = warp()
    f64 = wp.float64

    @wp.func
    def deformation_columns(x0: wp.vec3d, x1: wp.vec3d, x2: wp.vec3d, r: wp.mat22d):
        """The columns c0, c1 of the deformation gradient F = Ds Dm⁻¹ of a face with corners
        x0, x1, x2 and Dm⁻¹ = r."""
        e1 = x1 - x0
        e2 = x2 - x0
        return e1 * r[0, 0] + e2 * r[1, 0], e1 * r[0, 1] + e2 * r[1, 1]

    @wp.func
    def green_strain(c0: wp.vec3d, c1: wp.vec3d):
        """Green strain G = ½(FᵀF − I) of F = [c0 c1]: G00, G01, G11."""
        return f64(0.5) * (wp.dot(c0, c0) - f64(1.0)), f64(0.5) * wp.dot(c0, c1), f64(0.5) * (wp.dot(c1, c1) - f64(1.0))

    @wp.func
    def stress(g00: wp.float64, g01: wp.float64, g11: wp.float64, mu: wp.float64, lam: wp.float64):
        """StVK second Piola–Kirchhoff stress S = 2μG + λ tr(G) I: S00, S01, S11."""
        trace = lam * (g00 + g11)
        return f64(2.0) * mu * g00 + trace, f64(2.0) * mu * g01, f64(2.0) * mu * g11 + trace

    @wp.func
    def face_columns(x: wp.array2d(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                     rest_inv: wp.array(dtype=wp.mat22d), b: int, f: int):
        return deformation_columns(x[b, faces[f, 0]], x[b, faces[f, 1]], x[b, faces[f, 2]], rest_inv[f])

    @wp.func
    def face_strain_energy(x: wp.array2d(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                           rest_inv: wp.array(dtype=wp.mat22d), volume: wp.array(dtype=wp.float64),
                           mu: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64), b: int, f: int):
        """StVK energy V (μ‖G‖²_F + λ/2 tr(G)²) of face f of batch row b."""
        c0, c1 = face_columns(x, faces, rest_inv, b, f)
        g00, g01, g11 = green_strain(c0, c1)
        trace = g00 + g11
        psi = mu[f] * (g00 * g00 + f64(2.0) * g01 * g01 + g11 * g11) + f64(0.5) * lam[f] * trace * trace
        return volume[f] * psi

    @wp.kernel
    def strain_energy_kernel(x: wp.array2d(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                             rest_inv: wp.array(dtype=wp.mat22d), volume: wp.array(dtype=wp.float64),
                             mu: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64),
                             out: wp.array2d(dtype=wp.float64)):
        b, f = wp.tid()
        out[b, f] = face_strain_energy(x, faces, rest_inv, volume, mu, lam, b, f)

    @wp.func
    def strain_corner_forces(c0: wp.vec3d, c1: wp.vec3d, s00: wp.float64, s01: wp.float64, s11: wp.float64,
                             r: wp.mat22d, v: wp.float64):
        """The StVK forces −V P Dm⁻ᵀ on the corners 0, 1, 2 of a face with F = [c0 c1], stress S,
        Dm⁻¹ = r and volume v."""
        p0 = c0 * s00 + c1 * s01  # the columns of P = F S
        p1 = c0 * s01 + c1 * s11
        f1 = -v * (p0 * r[0, 0] + p1 * r[0, 1])
        f2 = -v * (p0 * r[1, 0] + p1 * r[1, 1])
        return -(f1 + f2), f1, f2

    @wp.kernel
    def strain_force_kernel(x: wp.array2d(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                            rest_inv: wp.array(dtype=wp.mat22d), volume: wp.array(dtype=wp.float64),
                            mu: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64),
                            out: wp.array2d(dtype=wp.vec3d)):
        b, f = wp.tid()
        c0, c1 = face_columns(x, faces, rest_inv, b, f)
        g00, g01, g11 = green_strain(c0, c1)
        s00, s01, s11 = stress(g00, g01, g11, mu[f], lam[f])
        f0, f1, f2 = strain_corner_forces(c0, c1, s00, s01, s11, rest_inv[f], volume[f])
        wp.atomic_add(out, b, faces[f, 0], f0)
        wp.atomic_add(out, b, faces[f, 1], f1)
        wp.atomic_add(out, b, faces[f, 2], f2)

    @wp.func
    def atan2_f64(y: wp.float64, x: wp.float64):
        """atan2(y, x) within about an ulp, at half the cost of `wp.atan2` on the CPU (which calls
        the C library's): the ratio of the smaller to the larger magnitude, t = lo/hi ∈ [0, 1],
        reduced to |r| ≤ 0.66 by atan t = π/4 + atan((t − 1)/(t + 1)) above 0.66 (r = (lo − hi)/(lo
        + hi) there, one division), then Cephes' rational approximation atan r ≈ r + r z P(z)/Q(z),
        z = r², and the quadrant; π/4, π/2 and π carry their rounding errors as second terms.
        atan2(0, 0) = 0."""
        ay = wp.abs(y)
        ax = wp.abs(x)
        hi = wp.max(ay, ax)
        lo = wp.min(ay, ax)
        a = f64(0.0)
        if hi > f64(0.0):
            reduced = lo > f64(0.66) * hi
            r = f64(0.0)
            if reduced:
                r = (lo - hi) / (lo + hi)
            else:
                r = lo / hi
            z = r * r
            p = (((f64(-8.750608600031904122785e-1) * z - f64(1.615753718733365076637e1)) * z
                  - f64(7.500855792314704667340e1)) * z - f64(1.228866684490136173410e2)) * z \
                - f64(6.485021904942025371773e1)
            q = ((((z + f64(2.485846490142306297962e1)) * z + f64(1.650270098316988542046e2)) * z
                  + f64(4.328810604912902668951e2)) * z + f64(4.853903996359136964868e2)) * z \
                + f64(1.945506571482613964425e2)
            a = r + r * z * p / q
            if reduced:
                a = f64(0.7853981633974483) + (a + f64(3.061616997868383e-17))
            if ay > ax:
                a = f64(1.5707963267948966) - (a - f64(6.123233995736766e-17))
            if x < f64(0.0):
                a = f64(3.141592653589793) - (a - f64(1.2246467991473532e-16))
            if y < f64(0.0):
                a = -a
        return a

    @wp.func_grad(atan2_f64)
    def atan2_f64_grad(y: wp.float64, x: wp.float64, adj_ret: wp.float64):
        """The exact derivatives (x, −y)/(x² + y²), not those of the approximation."""
        scale = adj_ret / (x * x + y * y)
        wp.adjoint[y] += scale * x
        wp.adjoint[x] -= scale * y

    @wp.func
    def hinge_angle(edge: wp.vec3d, n_a: wp.vec3d, n_b: wp.vec3d):
        """Signed dihedral angle θ = atan2((n_a × n_b)·ê, n_a·n_b), zero when flat (both arguments
        taken times |e|: the same angle, without a division)."""
        return atan2_f64(wp.dot(wp.cross(n_a, n_b), edge), wp.dot(n_a, n_b) * wp.length(edge))

    @wp.func
    def angle_gradients(edge: wp.vec3d, d2: wp.vec3d, d3: wp.vec3d, n_a: wp.vec3d, n_b: wp.vec3d):
        """∇θ w.r.t. the hinge's vertices v0 … v3 (edge = x1 − x0, d2 = x2 − x0, d3 = x3 − x0,
        n_a = edge × d2, n_b = d3 × edge), in closed form: the opposite corners move along their
        face normals with 1/height, the shared edge's ends take the balancing share by the
        corners' projections on the edge."""
        edge_sq = wp.dot(edge, edge)
        edge_len = wp.sqrt(edge_sq)
        g2 = -(edge_len / wp.dot(n_a, n_a)) * n_a
        g3 = -(edge_len / wp.dot(n_b, n_b)) * n_b
        inv_sq = f64(1.0) / edge_sq
        alpha_a = wp.dot(d2, edge) * inv_sq
        alpha_b = wp.dot(d3, edge) * inv_sq
        return -(f64(1.0) - alpha_a) * g2 - (f64(1.0) - alpha_b) * g3, -alpha_a * g2 - alpha_b * g3, g2, g3

    @wp.kernel
    def hinge_angle_kernel(x: wp.array2d(dtype=wp.vec3d), hinges: wp.array2d(dtype=wp.int32),
                           out: wp.array2d(dtype=wp.float64)):
        b, h = wp.tid()
        x0 = x[b, hinges[h, 0]]
        edge = x[b, hinges[h, 1]] - x0
        out[b, h] = hinge_angle(edge, wp.cross(edge, x[b, hinges[h, 2]] - x0),
                                wp.cross(x[b, hinges[h, 3]] - x0, edge))

    @wp.func
    def hinge_bend_energy(x: wp.array2d(dtype=wp.vec3d), hinges: wp.array2d(dtype=wp.int32),
                          stiffness: wp.array(dtype=wp.float64), b: int, h: int):
        """Dihedral bending energy k θ²/2 of hinge h of batch row b."""
        x0 = x[b, hinges[h, 0]]
        edge = x[b, hinges[h, 1]] - x0
        n_a = wp.cross(edge, x[b, hinges[h, 2]] - x0)  # |n_a| = 2 · area of face (v0, v1, v2)
        n_b = wp.cross(x[b, hinges[h, 3]] - x0, edge)  # |n_b| = 2 · area of face (v0, v3, v1)
        theta = hinge_angle(edge, n_a, n_b)
        return f64(0.5) * stiffness[h] * theta * theta

    @wp.kernel
    def bend_energy_kernel(x: wp.array2d(dtype=wp.vec3d), hinges: wp.array2d(dtype=wp.int32),
                           stiffness: wp.array(dtype=wp.float64), out: wp.array2d(dtype=wp.float64)):
        b, h = wp.tid()
        out[b, h] = hinge_bend_energy(x, hinges, stiffness, b, h)

    @wp.func
    def hinge_gradients(x: wp.array2d(dtype=wp.vec3d), hinges: wp.array2d(dtype=wp.int32), b: int, h: int):
        """θ of hinge h of batch row b and its gradients w.r.t. the hinge's vertices v0 … v3."""
        x0 = x[b, hinges[h, 0]]
        edge = x[b, hinges[h, 1]] - x0
        d2 = x[b, hinges[h, 2]] - x0
        d3 = x[b, hinges[h, 3]] - x0
        n_a = wp.cross(edge, d2)
        n_b = wp.cross(d3, edge)
        g0, g1, g2, g3 = angle_gradients(edge, d2, d3, n_a, n_b)
        return hinge_angle(edge, n_a, n_b), g0, g1, g2, g3

    @wp.kernel
    def bend_force_kernel(x: wp.array2d(dtype=wp.vec3d), hinges: wp.array2d(dtype=wp.int32),
                          stiffness: wp.array(dtype=wp.float64), out: wp.array2d(dtype=wp.vec3d)):
        b, h = wp.tid()
        theta, g0, g1, g2, g3 = hinge_gradients(x, hinges, b, h)
        scale = -stiffness[h] * theta
        wp.atomic_add(out, b, hinges[h, 0], scale * g0)
        wp.atomic_add(out, b, hinges[h, 1], scale * g1)
        wp.atomic_add(out, b, hinges[h, 2], scale * g2)
        wp.atomic_add(out, b, hinges[h, 3], scale * g3)

    return {"wp": wp, "atan2": atan2_f64, "deformation_columns": deformation_columns, "green_strain": green_strain, "stress": stress,
            "angle_gradients": angle_gradients, "strain_corner_forces": strain_corner_forces,
            "hinge_gradients": hinge_gradients, "face_columns": face_columns, "face_strain_energy": face_strain_energy,
            "hinge_bend_energy": hinge_bend_energy, "strain_energy": strain_energy_kernel, "strain_force": strain_force_kernel,
            "hinge_angle": hinge_angle_kernel, "bend_energy": bend_energy_kernel, "bend_force": bend_force_kernel}


_WARP_DTYPES = {  # torch dtype, trailing shape → the Warp element type of an array's entries
    (torch.float64, ()): "float64", (torch.float64, (3,)): "vec3d", (torch.float64, (2, 2)): "mat22d",
    (torch.float64, (3, 3)): "mat33d", (torch.int32, ()): "int32",
}


def _to_warp(wp, tensor: Tensor, element_dims: int):
    dtype = getattr(wp, _WARP_DTYPES[tensor.dtype, tuple(tensor.shape[tensor.ndim - element_dims:])])
    return launch_arg(tensor, dtype)


class _ElementKernel(torch.autograd.Function):
    """out = kernel(x, constants, scalars) with its Warp adjoint as the backward (module docstring).

    x (B, V, 3) float64 contiguous; constants: the kernel's array inputs after x, as (tensor, number
    of trailing element dims) pairs, rows ↔ elements; scalars: its number inputs after those;
    out_shape: (B, N) for per-element values, (B, V, 3) for forces or (B, V, 3, 3) for blocks.
    """

    @staticmethod
    def forward(ctx, x: Tensor, kernel, num_elements: int, constants: tuple, scalars: tuple,
                out_shape: tuple) -> Tensor:
        wp = _kernels()["wp"]
        out = torch.zeros(out_shape, dtype=torch.float64, device=x.device)
        per_vertex = len(out_shape) > 2

        def launch(lo: int, hi: int) -> None:
            recorded = _recorded(kernel, False, x, lo, hi, constants, scalars, out_shape)
            _replay(recorded, [(0, False, _to_warp(wp, x, 1)),
                               (1 + len(constants) + len(scalars), False,
                                _to_warp(wp, out if per_vertex else out[:, lo:hi], len(out_shape) - 2))])

        if num_elements and x.shape[0]:
            with torch_stream(x.device):
                run_parts(launch, _parts(x, constants[0][0]), "elements")
        ctx.save_for_backward(x)
        ctx.launch = (kernel, num_elements, constants, scalars, out_shape)
        return out

    @staticmethod
    def backward(ctx, grad_out: Tensor):
        if torch.is_grad_enabled():  # a graph of this backward (create_graph=True) would miss x
            raise RuntimeError("the element kernels are differentiable once: their backward cannot be "
                               "differentiated again (create_graph=True, torch.func.hessian)")
        (x,) = ctx.saved_tensors
        kernel, num_elements, constants, scalars, out_shape = ctx.launch
        wp = _kernels()["wp"]
        grad_x = torch.zeros_like(x)
        if num_elements and x.shape[0]:
            out = torch.zeros(out_shape, dtype=torch.float64, device=x.device)
            grad_out = grad_out.to(torch.float64).contiguous()
            per_vertex = len(out_shape) > 2
            index_out = 1 + len(constants) + len(scalars)

            def launch(lo: int, hi: int) -> None:
                rows = slice(None) if per_vertex else slice(lo, hi)
                recorded = _recorded(kernel, True, x, lo, hi, constants, scalars, out_shape)
                _replay(recorded, [(0, False, _to_warp(wp, x, 1)),
                                   (index_out, False, _to_warp(wp, out[:, rows], len(out_shape) - 2)),
                                   (0, True, _to_warp(wp, grad_x, 1)),
                                   (index_out, True, _to_warp(wp, grad_out[:, rows], len(out_shape) - 2))])

            with torch_stream(x.device):
                run_parts(launch, _parts(x, constants[0][0]), "elements")
        return grad_x, None, None, None, None, None


def _replay(recorded, arrays: list) -> None:
    """Launch `recorded` with these arrays set first: (argument index, of the adjoint, array
    descriptor). A descriptor keeps its tensor alive (`_ref`); the ones left in the recorded
    launch's arguments are let go after the launch (the next replay sets its own)."""
    for index, adjoint, array in arrays:
        recorded.set_param_at_index_from_ctype(index, array, adjoint=adjoint)
    recorded.launch()
    for _, _, array in arrays:
        array._ref = array._gradref = None


def _unpinned(array):
    """An array descriptor that does not keep its tensor alive (its owner checks that it lives)."""
    array._ref = array._gradref = None
    return array


#: Recorded launches per thread (`_recorded`), the most recently used kept.
_RECORDED = threading.local()
_RECORDED_SIZE = 64


def _recorded(kernel, adjoint: bool, x: Tensor, lo: int, hi: int, constants: tuple, scalars: tuple, out_shape: tuple):
    """The launch of `kernel` (forward, or with `adjoint` its adjoint) over elements [lo, hi) of a
    batch of x.shape[0] rows with these constants and scalars, recorded once (`record_cmd`) and
    replayed: packing a launch's arguments costs more than a small kernel's work on the CPU, and
    only x and the output (and in the adjoint their gradients) change from call to call; the
    caller sets those. Kept per thread (a replay mutates its arguments), keyed by the constants'
    identities and data pointers and checked against weak references to them (a recycled id makes
    the launch again; the entry does not keep a batch's constants alive). The constants' adjoints go to scratch
    arrays of the entry that nobody reads."""
    cache = _RECORDED.__dict__.setdefault("launches", collections.OrderedDict())
    key = (kernel, adjoint, x.device, x.shape[0], lo, hi, tuple((id(t), t.data_ptr()) for t, _ in constants), scalars,
           out_shape[2:])
    entry = cache.get(key)
    if entry is None or any(ref() is not t for ref, (t, _) in zip(entry[1], constants)):
        wp = _kernels()["wp"]
        x_ct = _to_warp(wp, x, 1)
        parts = [_unpinned(_to_warp(wp, t[lo:hi], d)) for t, d in constants]
        out = torch.zeros((x.shape[0], *out_shape[1:]) if len(out_shape) > 2 else (x.shape[0], hi - lo),
                          dtype=torch.float64, device=x.device)
        out_ct = _to_warp(wp, out, len(out_shape) - 2)
        scratch, adjoint_args = [], {}
        if adjoint:  # integer constants have no adjoint: their own arrays stand in
            scratch = [torch.zeros_like(t[lo:hi]) for t, _ in constants if t.is_floating_point()]
            held = iter(scratch)
            adjoint_args = {"adj_inputs": [x_ct, *(_unpinned(_to_warp(wp, next(held), d)) if t.is_floating_point() else part
                                                   for (t, d), part in zip(constants, parts)),
                                           *(type(v)(0) for v in scalars)],
                            "adj_outputs": [out_ct], "adjoint": True}
        launch = wp.launch(kernel, dim=(x.shape[0], hi - lo), device=wp.device_from_torch(x.device),
                           inputs=[x_ct, *parts, *scalars], outputs=[out_ct], record_cmd=True, **adjoint_args)
        entry = cache[key] = (launch, [weakref.ref(t) for t, _ in constants], scratch)
        while len(cache) > _RECORDED_SIZE:
            cache.popitem(last=False)
    cache.move_to_end(key)
    return entry[0]


def _parts(x: Tensor, elements: Tensor) -> list[tuple[int, int]]:
    """The element ranges a launch over `elements` (N, k) runs in: on the CPU with several torch
    threads and one leading batch row, the garments of a packed batch, split between threads
    (their vertices are disjoint, so every kernel's sums into vertices stay those of one launch;
    `physdrape.threads`); else one range. One garment is not split: its kernels' parts, a fraction
    of a millisecond, gain less from a second thread than handing them over costs."""
    threads = torch.get_num_threads() if x.device.type == "cpu" and x.shape[0] == 1 else 1
    return disjoint_parts(elements, threads)


#: Kernel-typed copies of the cloth's coefficients (float64 / int32), per tensor they were made
#: from: a solver evaluates the same cloth dozens of times per drape.
_CONSTANTS = TensorMemo(256)


def kernel_constant(t: Tensor) -> Tensor:
    """t as float64 (floating) or int32 (integer), contiguous: t itself when it is already, else a
    copy made once per tensor and reused while that tensor lives unmodified (`TensorMemo`)."""
    target = torch.float64 if t.is_floating_point() else torch.int32
    if t.dtype == target and t.is_contiguous():
        return t
    return _CONSTANTS.get(t, lambda u: u.to(target).contiguous())


def run_kernel(kernel, x: Tensor, constants: list[Tensor], element_dims: list[int], num_elements: int,
               out_dims: tuple[int, ...] | None, scalars: tuple = ()) -> Tensor:
    """One launch of a Warp element kernel over `num_elements` elements, differentiable once in x
    (its backward is the kernel's adjoint; the constants are not differentiated).

    The kernel's inputs are x (B, V, 3) as vec3d, then each of `constants` (rows ↔ elements; the
    first is the elements' vertex table, by which a packed batch's launch is split between threads)
    with its number of trailing element dims, then `scalars` (numbers); its output is one value per
    element (``out_dims`` None: (..., N)) or per vertex (``out_dims`` (3,) or (3, 3): (..., V, 3) or
    (..., V, 3, 3)), summed atomically. x (..., V, 3) any float dtype; computed in float64 and
    returned in x's dtype.
    """
    if any(t.requires_grad for t in constants):
        raise ValueError("the cloth's coefficients are constants of the element kernels: they are not "
                         "differentiated (detach them, or differentiate with respect to x only)")
    lead = x.shape[:-2]
    num_verts = x.shape[-2]
    batch = math.prod(lead)
    x64 = x.reshape(batch, num_verts, 3).to(torch.float64).contiguous()
    packed = tuple(kernel_constant(t) for t in constants)
    out_shape = (batch, num_elements) if out_dims is None else (batch, num_verts, *out_dims)
    out = _ElementKernel.apply(x64, kernel, num_elements, tuple(zip(packed, element_dims)), tuple(scalars), out_shape)
    return out.reshape(*lead, *out_shape[1:]).to(x.dtype)


def _run(name: str, x: Tensor, constants: list[Tensor], element_dims: list[int], num_elements: int,
         per_vertex: bool) -> Tensor:
    return run_kernel(_kernels()[name], x, constants, element_dims, num_elements, (3,) if per_vertex else None)


def strain_energy_per_face(x: Tensor, faces: Tensor, rest_inv: Tensor, volume: Tensor, mu: Tensor,
                           lam: Tensor) -> Tensor:
    """StVK energy V (μ‖G‖²_F + λ/2 tr(G)²) per face [J], x (..., V, 3) [m] → (..., F)."""
    return _run("strain_energy", x, [faces, rest_inv, volume, mu, lam], [0, 2, 0, 0, 0], faces.shape[0], False)


def strain_force(x: Tensor, faces: Tensor, rest_inv: Tensor, volume: Tensor, mu: Tensor, lam: Tensor) -> Tensor:
    """−∇ of the StVK energy [N], x (..., V, 3) [m] → (..., V, 3)."""
    return _run("strain_force", x, [faces, rest_inv, volume, mu, lam], [0, 2, 0, 0, 0], faces.shape[0], True)


def hinge_angles(x: Tensor, hinges: Tensor) -> Tensor:
    """Signed dihedral angle per hinge [rad], x (..., V, 3) [m] → (..., H)."""
    return _run("hinge_angle", x, [hinges], [0], hinges.shape[0], False)


def bend_energy_per_hinge(x: Tensor, hinges: Tensor, stiffness: Tensor) -> Tensor:
    """Dihedral bending energy k θ²/2 per hinge [J], x (..., V, 3) [m] → (..., H)."""
    return _run("bend_energy", x, [hinges, stiffness], [0, 0], hinges.shape[0], False)


def bend_force(x: Tensor, hinges: Tensor, stiffness: Tensor) -> Tensor:
    """−∇ of the dihedral bending energy [N], x (..., V, 3) [m] → (..., V, 3)."""
    return _run("bend_force", x, [hinges, stiffness], [0, 0], hinges.shape[0], True)

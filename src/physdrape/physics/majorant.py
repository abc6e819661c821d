"""The stretching solver's stiffness: a PSD majorant of the garment's Hessian, as NVIDIA Warp kernels.

The two-level preconditioner of `physdrape.model.stretching_solver` needs, at every step, each
vertex's 3×3 stiffness block (block Jacobi) and, every few steps, the 3×3 blocks of every pair of
vertices that share a face (the Galerkin product of `physdrape.physics.coarse_space`). Both come
from one closed-form PSD majorant of ∇²(E_strain + E_bend), without eigendecompositions:

- Strain (StVK). With F = Ds·Dm⁻¹ = Σ_a x_a w_aᵀ (w_a the rows of Dm⁻¹, corner 0 taking minus
  their sum) and u_a = F w_a, the block of corners a, b of a face is
  ``V [(w_aᵀ |S| w_b) I + μ u_b u_aᵀ + λ u_a u_bᵀ + μ (w_a·w_b) F Fᵀ]``, where S = 2μG + λ tr(G) I
  is the second Piola–Kirchhoff stress and |S| the 2×2 stress with its eigenvalues replaced by
  their absolute values. Only the ``δ_cd S_lj`` term of the elasticity tensor can be indefinite
  (the μ and λ terms sum to ``2μ‖sym(FᵀV)‖² + λ tr(FᵀV)²`` ≥ 0 for any direction V), so |S| in
  place of S gives a PSD tensor that is ≥ the exact one, and equal to it where S is PSD
  (stretch). |S| rather than its PSD part keeps a compressed face stiff across its plane
  (absolute-eigenvalue filtering, Chen et al. 2024): with S⁺ a compressed, flat patch is held out
  of plane by its bending stiffness alone, and preconditioned steps there throw it into
  mesh-scale wrinkles.
- Bending: the Gauss–Newton part k·∇θ∇θᵀ of each hinge (PSD by construction), added to the
  vertex blocks only (smooth coarse patches barely bend).

The kernels compute in float64 whatever the garment's dtype (a few thousand elements; the
coarse product is formed in float64 anyway) and run where the tensors live, on the CPU or on
CUDA, one thread per face or hinge, summing into the vertices and pairs atomically. Nothing here
is differentiated: the solver's preconditioner is a constant of each step.
"""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.physics import element_kernels
from physdrape.physics.cloth import Cloth
from physdrape.threads import disjoint_parts, run_parts
from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

__all__ = ["pair_blocks", "vertex_blocks", "vertex_compliance"]


@defined_once
def _kernels():
    """Define the kernels (first call only; Warp caches the compiled code on disk)."""
    wp = warp()
    f64 = wp.float64
    shared = element_kernels._kernels()  # the element kernels' F, G, S and ∇θ
    deformation_columns, green_strain, stress = shared["deformation_columns"], shared["green_strain"], shared["stress"]
    angle_gradients = shared["angle_gradients"]

    @wp.func
    def abs_part(s: wp.mat22d) -> wp.mat22d:
        """|S| of a symmetric 2×2 matrix: S = hi·P + lo·(I − P) → |hi| P + |lo| (I − P)."""
        mean = f64(0.5) * (s[0, 0] + s[1, 1])
        half = wp.sqrt(f64(0.25) * (s[0, 0] - s[1, 1]) * (s[0, 0] - s[1, 1]) + s[0, 1] * s[0, 1])
        lo = mean - half
        hi = mean + half
        eye = wp.identity(n=2, dtype=wp.float64)
        proj = f64(0.5) * eye
        if hi - lo > f64(0.0):
            proj = (s - lo * eye) / (hi - lo)
        return wp.abs(hi) * proj + wp.abs(lo) * (eye - proj)

    @wp.func
    def corner_block(wa: wp.vec2d, ua: wp.vec3d, wb: wp.vec2d, ub: wp.vec3d, s_abs: wp.mat22d, fft: wp.mat33d,
                     mu: wp.float64, lam: wp.float64, volume: wp.float64) -> wp.mat33d:
        """The strain majorant's block of corners a, b (module docstring)."""
        return volume * (wp.dot(wa, s_abs * wb) * wp.identity(n=3, dtype=wp.float64) + mu * wp.outer(ub, ua)
                         + lam * wp.outer(ua, ub) + mu * wp.dot(wa, wb) * fft)

    @wp.func
    def face_state(x: wp.array(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                   rest_inv: wp.array(dtype=wp.mat22d), mu: wp.float64, lam: wp.float64, f: int):
        """Corner weights w_a, u_a = F w_a, |S| and F Fᵀ of face f."""
        r = rest_inv[f]
        c0, c1 = deformation_columns(x[faces[f, 0]], x[faces[f, 1]], x[faces[f, 2]], r)  # the columns of F
        g00, g01, g11 = green_strain(c0, c1)
        s00, s01, s11 = stress(g00, g01, g11, mu, lam)
        s = wp.mat22d(s00, s01, s01, s11)
        w1 = wp.vec2d(r[0, 0], r[0, 1])
        w2 = wp.vec2d(r[1, 0], r[1, 1])
        w0 = -(w1 + w2)
        u0 = c0 * w0[0] + c1 * w0[1]
        u1 = c0 * w1[0] + c1 * w1[1]
        u2 = c0 * w2[0] + c1 * w2[1]
        return w0, w1, w2, u0, u1, u2, abs_part(s), wp.outer(c0, c0) + wp.outer(c1, c1)

    @wp.kernel(enable_backward=False)
    def strain_vertex_kernel(x: wp.array(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                             rest_inv: wp.array(dtype=wp.mat22d), volume: wp.array(dtype=wp.float64),
                             mu: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.mat33d)):
        f = wp.tid()
        m, l, v = mu[f], lam[f], volume[f]
        w0, w1, w2, u0, u1, u2, s_abs, fft = face_state(x, faces, rest_inv, m, l, f)
        wp.atomic_add(out, faces[f, 0], corner_block(w0, u0, w0, u0, s_abs, fft, m, l, v))
        wp.atomic_add(out, faces[f, 1], corner_block(w1, u1, w1, u1, s_abs, fft, m, l, v))
        wp.atomic_add(out, faces[f, 2], corner_block(w2, u2, w2, u2, s_abs, fft, m, l, v))

    @wp.kernel(enable_backward=False)
    def strain_pair_kernel(x: wp.array(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                           rest_inv: wp.array(dtype=wp.mat22d), volume: wp.array(dtype=wp.float64),
                           mu: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64), pair: wp.array2d(dtype=wp.int32),
                           out: wp.array(dtype=wp.mat33d)):
        f = wp.tid()
        m, l, v = mu[f], lam[f], volume[f]
        w0, w1, w2, u0, u1, u2, s_abs, fft = face_state(x, faces, rest_inv, m, l, f)
        wp.atomic_add(out, pair[f, 0], corner_block(w0, u0, w0, u0, s_abs, fft, m, l, v))
        wp.atomic_add(out, pair[f, 1], corner_block(w0, u0, w1, u1, s_abs, fft, m, l, v))
        wp.atomic_add(out, pair[f, 2], corner_block(w0, u0, w2, u2, s_abs, fft, m, l, v))
        wp.atomic_add(out, pair[f, 3], corner_block(w1, u1, w0, u0, s_abs, fft, m, l, v))
        wp.atomic_add(out, pair[f, 4], corner_block(w1, u1, w1, u1, s_abs, fft, m, l, v))
        wp.atomic_add(out, pair[f, 5], corner_block(w1, u1, w2, u2, s_abs, fft, m, l, v))
        wp.atomic_add(out, pair[f, 6], corner_block(w2, u2, w0, u0, s_abs, fft, m, l, v))
        wp.atomic_add(out, pair[f, 7], corner_block(w2, u2, w1, u1, s_abs, fft, m, l, v))
        wp.atomic_add(out, pair[f, 8], corner_block(w2, u2, w2, u2, s_abs, fft, m, l, v))

    @wp.kernel(enable_backward=False)
    def bend_vertex_kernel(x: wp.array(dtype=wp.vec3d), hinges: wp.array2d(dtype=wp.int32),
                           stiffness: wp.array(dtype=wp.float64), out: wp.array(dtype=wp.mat33d)):
        h = wp.tid()
        x0 = x[hinges[h, 0]]
        edge = x[hinges[h, 1]] - x0
        d2 = x[hinges[h, 2]] - x0
        d3 = x[hinges[h, 3]] - x0
        n_a = wp.cross(edge, d2)
        n_b = wp.cross(d3, edge)
        g0, g1, g2, g3 = angle_gradients(edge, d2, d3, n_a, n_b)  # ∇θ
        k = stiffness[h]
        wp.atomic_add(out, hinges[h, 0], k * wp.outer(g0, g0))
        wp.atomic_add(out, hinges[h, 1], k * wp.outer(g1, g1))
        wp.atomic_add(out, hinges[h, 2], k * wp.outer(g2, g2))
        wp.atomic_add(out, hinges[h, 3], k * wp.outer(g3, g3))

    @wp.kernel(enable_backward=False)
    def compliance_kernel(blocks: wp.array(dtype=wp.mat33d), extra: wp.array(dtype=wp.mat33d), with_extra: int,
                          rel: wp.float64, tiny: wp.float64, out: wp.array(dtype=wp.mat33d)):
        """(K + rel·max(tr K, tiny)·I)⁻¹ of each vertex's K = blocks (+ extra)."""
        v = wp.tid()
        k = blocks[v]
        if with_extra != 0:
            k = k + extra[v]
        floor = rel * wp.max(wp.trace(k), tiny)
        out[v] = wp.inverse(k + floor * wp.identity(n=3, dtype=wp.float64))

    return wp, strain_vertex_kernel, strain_pair_kernel, bend_vertex_kernel, compliance_kernel


def _launch(kernel, x: Tensor, elements: Tensor, per_element: list[tuple[Tensor, str]], out: Tensor) -> None:
    """kernel over the rows of `elements` (N, k) int32: inputs x (V, 3) as vec3d, then each
    per-element tensor (rows ↔ elements) as its Warp type, output `out` (rows: vertices or vertex
    pairs, mat33d). On the CPU with several torch threads, the rows are split between threads where
    they touch disjoint vertices (the garments of a packed batch, `physdrape.threads`)."""
    wp = warp()
    device = wp.device_from_torch(x.device)
    target = launch_arg(out, wp.mat33d)
    x64 = launch_arg(x, wp.vec3d)

    def launch(lo: int, hi: int) -> None:
        wp.launch(kernel, dim=hi - lo, device=device, outputs=[target],
                  inputs=[x64, *(launch_arg(t[lo:hi], getattr(wp, kind)) for t, kind in per_element)])

    threads = torch.get_num_threads() if x.device.type == "cpu" else 1
    with torch_stream(x.device):
        run_parts(launch, disjoint_parts(elements, threads), "elements")


def _strain_constants(cloth: Cloth) -> list[tuple[Tensor, str]]:
    """The strain kernels' per-face arguments after x: faces, Dm⁻¹, V, μ, λ (int32 / float64,
    the element kernels' cached copies)."""
    constant = element_kernels.kernel_constant
    return [(constant(cloth.faces), "int32"), (constant(cloth.rest_inv), "mat22d"), (constant(cloth.volume), "float64"),
            (constant(cloth.mu), "float64"), (constant(cloth.lam), "float64")]


@torch.no_grad()
def vertex_blocks(x: Tensor, cloth: Cloth) -> Tensor:
    """3×3 diagonal blocks per vertex of the PSD majorant of ∇²(E_strain + E_bend) (module docstring).

    x (V, 3) [m] → (V, 3, 3) [N/m] in x's dtype, symmetric PSD. The strain part equals the
    diagonal blocks of `physics.hessians.strain_hessian` wherever every face's stress S is PSD;
    the bending part is Gauss–Newton.
    """
    return _vertex_blocks64(x, cloth).to(x.dtype)


def _vertex_blocks64(x: Tensor, cloth: Cloth) -> Tensor:
    """`vertex_blocks` in float64."""
    _, strain_vertex, _, bend_vertex, _ = _kernels()
    out = torch.zeros(cloth.num_verts, 3, 3, dtype=torch.float64, device=x.device)
    x64 = x.detach().to(torch.float64).contiguous()
    if cloth.faces.shape[0]:
        strain = _strain_constants(cloth)
        _launch(strain_vertex, x64, strain[0][0], strain, out)
    if cloth.hinges.shape[0]:
        hinges = element_kernels.kernel_constant(cloth.hinges)
        _launch(bend_vertex, x64, hinges, [(hinges, "int32"),
                                           (element_kernels.kernel_constant(cloth.bend_stiffness), "float64")], out)
    return out


@torch.no_grad()
def vertex_compliance(x: Tensor, cloth: Cloth, extra: Tensor | None = None, *, rel: float) -> Tensor:
    """Inverses of the regularised per-vertex stiffness blocks, (K_i + rel · max(tr K_i, tiny) · I)⁻¹
    with K_i = `vertex_blocks` (+ extra (V, 3, 3) [N/m], e.g. the contact's), (V, 3, 3) [m/N] in x's
    dtype, computed in float64. The floor relative to each vertex's own stiffness keeps K_i
    invertible (a vertex of an unstretched flat patch has a rank-deficient block); tiny is the
    smallest normal number of x's dtype (a vertex without stiffness)."""
    wp, _, _, _, compliance = _kernels()
    blocks = _vertex_blocks64(x, cloth)
    if extra is not None:
        if tuple(extra.shape) != tuple(blocks.shape):
            raise ValueError(f"extra blocks must have shape {tuple(blocks.shape)}, got {tuple(extra.shape)}")
        extra = extra.detach().to(torch.float64).contiguous()
    out = torch.empty_like(blocks)
    if cloth.num_verts:
        with torch_stream(x.device):
            wp.launch(compliance, dim=cloth.num_verts, device=wp.device_from_torch(x.device),
                      inputs=[launch_arg(blocks, wp.mat33d), launch_arg(blocks if extra is None else extra, wp.mat33d),
                              int(extra is not None), float(rel), float(torch.finfo(x.dtype).tiny)],
                      outputs=[launch_arg(out, wp.mat33d)])
    return out.to(x.dtype)


@torch.no_grad()
def pair_blocks(x: Tensor, cloth: Cloth, pair_of_corner: Tensor, num_pairs: int) -> Tensor:
    """The strain majorant's 3×3 blocks summed per vertex pair, (num_pairs, 3, 3) float64 [N/m].

    pair_of_corner (F, 9) int32, on x's device: for face f and corners a, b, the pair that face
    f's block (a, b) is added to (rows of vertex a, columns of vertex b), entry 3a + b. With
    ``arange(9 F)`` the result is every face's 9×9 block, laid out as (F, a, b, 3, 3).
    """
    _, _, strain_pair, _, _ = _kernels()
    out = torch.zeros(num_pairs, 3, 3, dtype=torch.float64, device=x.device)
    if pair_of_corner.shape != (cloth.faces.shape[0], 9) or pair_of_corner.dtype != torch.int32:
        raise ValueError(f"pair_of_corner must be int32 of shape ({cloth.faces.shape[0]}, 9), "
                         f"got {pair_of_corner.dtype} {tuple(pair_of_corner.shape)}")
    if cloth.faces.shape[0]:  # a face's pairs are pairs of its garment: the garments' pairs are disjoint too
        strain = _strain_constants(cloth)
        _launch(strain_pair, x.detach().to(torch.float64).contiguous(), strain[0][0],
                [*strain, (pair_of_corner.contiguous(), "int32")], out)
    return out

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

The per-vertex blocks (and, at the steps that factorise the coarse space, the pair blocks) come
from the local-terms kernel, which also sums the force −∇Φ that the solver's step starts from
(strain, bending, gravity, an external force and the body contact on held planes, `LocalTerms`)
and the contact's Gauss–Newton blocks: a face's deformation and stress, and a hinge's angle
gradients, serve its force and its blocks at once, and a step's force and stiffness are one
launch (`physics.potential.GarmentPotential.local_terms` records it
on the solver's held planes). The per-element formulas are those of the element and contact
kernels (`physics.element_kernels`, `physics.contact_kernels`).

The kernels compute in float64 whatever the garment's dtype (a few thousand elements; the
coarse product is formed in float64 anyway) and run where the tensors live, on the CPU or on
CUDA, one thread per face, hinge or vertex, summing into the vertices and pairs atomically.
Nothing here is differentiated but the product of the pair blocks with a field (`pair_product`,
linear in the field: the solver's inner iterations): the solver's preconditioner is a constant of
each step, and its training differentiates the forces of the element kernels.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from physdrape.physics import contact_kernels, element_kernels
from physdrape.physics.cloth import Cloth
from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

__all__ = ["LocalTerms", "add_blocks", "compliance", "pair_blocks", "pair_product", "record_compliance",
           "record_local_terms", "vertex_blocks", "vertex_compliance"]


@defined_once
def _kernels():
    """Define the kernels (first call only; Warp caches the compiled code on disk)."""
    wp = warp()
    f64 = wp.float64
    shared = element_kernels._kernels()  # the element kernels' F, G, S, forces and ∇θ
    green_strain, stress = shared["green_strain"], shared["stress"]
    face_columns, strain_corner_forces = shared["face_columns"], shared["strain_corner_forces"]
    hinge_gradients = shared["hinge_gradients"]
    contact = contact_kernels.kernels()  # a sample's distance, force and block on its held plane
    plane_distance, sample_force, sample_block = contact["plane_distance"], contact["sample_force"], contact["sample_block"]
    spread = contact["spread"]

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
    def diagonal_block(wa: wp.vec2d, ua: wp.vec3d, s_abs: wp.mat22d, fft: wp.mat33d, mu: wp.float64, lam: wp.float64,
                       volume: wp.float64) -> wp.mat33d:
        """`corner_block` of a corner with itself: V [(w_aᵀ |S| w_a) I + (μ + λ) u_a u_aᵀ + μ |w_a|² F Fᵀ]."""
        return volume * (wp.dot(wa, s_abs * wa) * wp.identity(n=3, dtype=wp.float64) + (mu + lam) * wp.outer(ua, ua)
                         + mu * wp.dot(wa, wa) * fft)

    @wp.func
    def face_terms(c0: wp.vec3d, c1: wp.vec3d, s: wp.mat22d, r: wp.mat22d):
        """Corner weights w_a, u_a = F w_a, |S| and F Fᵀ of a face with F = [c0 c1], stress S and Dm⁻¹ = r."""
        w1 = wp.vec2d(r[0, 0], r[0, 1])
        w2 = wp.vec2d(r[1, 0], r[1, 1])
        w0 = -(w1 + w2)
        u0 = c0 * w0[0] + c1 * w0[1]
        u1 = c0 * w1[0] + c1 * w1[1]
        u2 = c0 * w2[0] + c1 * w2[1]
        return w0, w1, w2, u0, u1, u2, abs_part(s), wp.outer(c0, c0) + wp.outer(c1, c1)

    @wp.func
    def contact_terms(x: wp.array2d(dtype=wp.vec3d), corners: wp.array2d(dtype=wp.int32),
                      closest: wp.array(dtype=wp.vec3d), normal: wp.array(dtype=wp.vec3d), stiffness: wp.float64,
                      margin: wp.float64, band: wp.float64, s: int, force: wp.array2d(dtype=wp.vec3d),
                      contact: wp.array2d(dtype=wp.mat33d)):
        """Sample s's contact force and block on its held plane, onto its vertex or its face's corners."""
        d = plane_distance(x, corners, closest, normal, 0, s)
        if d < margin:
            spread(force, corners, 0, s, sample_force(d, normal[s], stiffness, margin), f64(3.0))
        if d < wp.max(band, margin):
            spread(contact, corners, 0, s, sample_block(d, normal[s], stiffness, margin, band), f64(9.0))

    @wp.kernel(enable_backward=False)
    def local_terms_kernel(x: wp.array2d(dtype=wp.vec3d), faces: wp.array2d(dtype=wp.int32),
                           rest_inv: wp.array(dtype=wp.mat22d), volume: wp.array(dtype=wp.float64),
                           mu: wp.array(dtype=wp.float64), lam: wp.array(dtype=wp.float64),
                           hinges: wp.array2d(dtype=wp.int32), bend_stiffness: wp.array(dtype=wp.float64),
                           mass: wp.array(dtype=wp.float64), gravity: wp.array(dtype=wp.vec3d),
                           vert_garment: wp.array(dtype=wp.int32), external: wp.array(dtype=wp.vec3d),
                           with_external: int, corners: wp.array2d(dtype=wp.int32), closest: wp.array(dtype=wp.vec3d),
                           normal: wp.array(dtype=wp.vec3d), with_planes: int, stiffness: wp.float64,
                           margin: wp.float64, band: wp.float64, face_lo: int, num_faces: int, hinge_lo: int,
                           num_hinges: int, vert_lo: int, num_verts: int, vertex_band: wp.array(dtype=wp.float64),
                           with_vertex_band: int, pair: wp.array2d(dtype=wp.int32), with_pairs: int,
                           force: wp.array2d(dtype=wp.vec3d), blocks: wp.array2d(dtype=wp.mat33d),
                           contact: wp.array2d(dtype=wp.mat33d), pairs: wp.array(dtype=wp.mat33d)):
        """One thread per face (its strain force and blocks, its centroid's contact), per hinge (its
        bending force and Gauss–Newton blocks) and per vertex (gravity, the external force, its own
        contact): the force −∇Φ (`force`), the strain and bending majorant's vertex blocks
        (`blocks`) and the contact's blocks (`contact`), each summed into the vertices (with
        `with_vertex_band`, a vertex's own sample takes its block's band from `vertex_band`); with
        `with_pairs`, also each face's 9 strain blocks summed into its corner pairs' (`pairs`, the
        pair of corners a, b of face f at pair[f, 3a + b]; block (b, a) = block (a, b)ᵀ)."""
        i = wp.tid()
        if i < num_faces:
            f = face_lo + i
            r = rest_inv[f]
            m = mu[f]
            l = lam[f]
            v = volume[f]
            c0, c1 = face_columns(x, faces, rest_inv, 0, f)
            g00, g01, g11 = green_strain(c0, c1)
            s00, s01, s11 = stress(g00, g01, g11, m, l)
            f0, f1, f2 = strain_corner_forces(c0, c1, s00, s01, s11, r, v)
            w0, w1, w2, u0, u1, u2, s_abs, fft = face_terms(c0, c1, wp.mat22d(s00, s01, s01, s11), r)
            a0 = faces[f, 0]
            a1 = faces[f, 1]
            a2 = faces[f, 2]
            wp.atomic_add(force, 0, a0, f0)
            wp.atomic_add(force, 0, a1, f1)
            wp.atomic_add(force, 0, a2, f2)
            d0 = diagonal_block(w0, u0, s_abs, fft, m, l, v)
            d1 = diagonal_block(w1, u1, s_abs, fft, m, l, v)
            d2 = diagonal_block(w2, u2, s_abs, fft, m, l, v)
            wp.atomic_add(blocks, 0, a0, d0)
            wp.atomic_add(blocks, 0, a1, d1)
            wp.atomic_add(blocks, 0, a2, d2)
            if with_pairs != 0:
                b01 = corner_block(w0, u0, w1, u1, s_abs, fft, m, l, v)
                b02 = corner_block(w0, u0, w2, u2, s_abs, fft, m, l, v)
                b12 = corner_block(w1, u1, w2, u2, s_abs, fft, m, l, v)
                wp.atomic_add(pairs, pair[f, 0], d0)
                wp.atomic_add(pairs, pair[f, 1], b01)
                wp.atomic_add(pairs, pair[f, 2], b02)
                wp.atomic_add(pairs, pair[f, 3], wp.transpose(b01))
                wp.atomic_add(pairs, pair[f, 4], d1)
                wp.atomic_add(pairs, pair[f, 5], b12)
                wp.atomic_add(pairs, pair[f, 6], wp.transpose(b02))
                wp.atomic_add(pairs, pair[f, 7], wp.transpose(b12))
                wp.atomic_add(pairs, pair[f, 8], d2)
            if with_planes != 0:  # the face's centroid sample: V + f
                contact_terms(x, corners, closest, normal, stiffness, margin, band, num_verts + f, force, contact)
        elif i < num_faces + num_hinges:
            h = hinge_lo + i - num_faces
            k = bend_stiffness[h]
            theta, g0, g1, g2, g3 = hinge_gradients(x, hinges, 0, h)
            scale = -k * theta
            wp.atomic_add(force, 0, hinges[h, 0], scale * g0)
            wp.atomic_add(force, 0, hinges[h, 1], scale * g1)
            wp.atomic_add(force, 0, hinges[h, 2], scale * g2)
            wp.atomic_add(force, 0, hinges[h, 3], scale * g3)
            wp.atomic_add(blocks, 0, hinges[h, 0], k * wp.outer(g0, g0))
            wp.atomic_add(blocks, 0, hinges[h, 1], k * wp.outer(g1, g1))
            wp.atomic_add(blocks, 0, hinges[h, 2], k * wp.outer(g2, g2))
            wp.atomic_add(blocks, 0, hinges[h, 3], k * wp.outer(g3, g3))
        else:
            j = vert_lo + i - num_faces - num_hinges
            own = mass[j] * gravity[vert_garment[j]]
            if with_external != 0:
                own = own + external[j]
            wp.atomic_add(force, 0, j, own)
            if with_planes != 0:
                own_band = band
                if with_vertex_band != 0:
                    own_band = vertex_band[j]
                contact_terms(x, corners, closest, normal, stiffness, margin, own_band, j, force, contact)

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

    @wp.kernel(enable_backward=False)
    def pair_product_kernel(blocks: wp.array(dtype=wp.mat33d), ends: wp.array2d(dtype=wp.int32),
                            v: wp.array(dtype=wp.vec3d), transpose: int, out: wp.array(dtype=wp.vec3d)):
        """out[a] += B_p v[b] for each pair p = (a, b) (transpose: out[b] += B_pᵀ v[a])."""
        p = wp.tid()
        a = ends[p, 0]
        b = ends[p, 1]
        if transpose == 0:
            wp.atomic_add(out, a, blocks[p] * v[b])
        else:
            wp.atomic_add(out, b, wp.transpose(blocks[p]) * v[a])

    @wp.kernel(enable_backward=False)
    def add_blocks_kernel(blocks: wp.array(dtype=wp.mat33d), rows: wp.array(dtype=wp.int32),
                          add: wp.array(dtype=wp.mat33d)):
        """blocks[rows[i]] += add[i] (the rows distinct: no two threads write one block)."""
        i = wp.tid()
        row = rows[i]
        blocks[row] = blocks[row] + add[i]

    return {"wp": wp, "local_terms": local_terms_kernel, "compliance": compliance_kernel,
            "pair_product": pair_product_kernel, "add_blocks": add_blocks_kernel}


@dataclass(frozen=True)
class LocalTerms:
    """What a solver step needs of each vertex at positions x, float64, (V, ...) each: the force
    −∇Φ (V, 3) [N] (strain, bending, gravity, the external force, the contact on held planes), the
    strain and bending majorant's 3×3 blocks (V, 3, 3) [N/m], the contact's Gauss–Newton blocks
    (V, 3, 3) [N/m] (zero without planes; plus any extra blocks the caller adds) and, where asked
    for, the inverses of their floored sums (V, 3, 3) [m/N] (`compliance`)."""

    force: Tensor
    blocks: Tensor
    contact: Tensor
    compliance: Tensor | None = None  # `compliance` of blocks + contact, where asked for
    pairs: Tensor | None = None  # the strain majorant's pair blocks (P, 3, 3) [N/m], where asked for (`pair_blocks`)


def record_local_terms(x: Tensor, cloth: Cloth, out: LocalTerms, part: tuple[int, ...], *, external: Tensor | None,
                       corners: Tensor | None, planes: tuple[Tensor, Tensor] | None, stiffness: float, margin: float,
                       band: float, pair_of_corner: Tensor | None = None, vertex_band: Tensor | None = None):
    """The launch of the local-terms kernel, recorded (`record_cmd`; None for an empty part): x (1,
    V, 3) float64, summed into `out` (zeroed by the caller), over the part's (face lo, hi, hinge
    lo, hi, vertex lo, hi) elements; external (V, 3) float64 or None; the contact samples' corner
    table (`contact.sample_corners`) and held planes (closest points, normals (V + F, 3) float64),
    or None; stiffness k_c [J/m³], margin ε [m] and the blocks' band [m] (`contact.plane_contact_blocks`);
    vertex_band (V,) float64: the band of each vertex's own sample instead, or None;
    pair_of_corner (F, 9) int32: also the pair blocks into `out.pairs` (`pair_blocks`), or None.
    The caller keeps the tensors alive while the launch is replayed."""
    kernels = _kernels()
    wp = kernels["wp"]
    face_lo, face_hi, hinge_lo, hinge_hi, vert_lo, vert_hi = part
    dim = (face_hi - face_lo) + (hinge_hi - hinge_lo) + (vert_hi - vert_lo)
    if not dim:
        return None
    constant = element_kernels.kernel_constant
    idle = torch.zeros(1, 3, dtype=torch.float64, device=x.device)
    closest, normal = planes if planes is not None else (idle, idle)
    corners = corners if planes is not None else idle.to(torch.int32)
    typed = [(cloth.faces, wp.int32), (cloth.rest_inv, wp.mat22d), (cloth.volume, wp.float64), (cloth.mu, wp.float64),
             (cloth.lam, wp.float64), (cloth.hinges, wp.int32), (cloth.bend_stiffness, wp.float64),
             (cloth.mass, wp.float64), (cloth.gravity, wp.vec3d), (cloth.vert_garment, wp.int32)]
    inputs = [launch_arg(x, wp.vec3d), *(launch_arg(constant(t), kind) for t, kind in typed),
              launch_arg(idle if external is None else external, wp.vec3d), int(external is not None),
              launch_arg(corners, wp.int32), launch_arg(closest, wp.vec3d), launch_arg(normal, wp.vec3d),
              int(planes is not None), float(stiffness), float(margin), float(band), face_lo, face_hi - face_lo,
              hinge_lo, hinge_hi - hinge_lo, vert_lo, cloth.num_verts,
              launch_arg(idle[0] if vertex_band is None else vertex_band, wp.float64), int(vertex_band is not None),
              launch_arg(idle.to(torch.int32) if pair_of_corner is None else pair_of_corner, wp.int32),
              int(pair_of_corner is not None)]
    if pair_of_corner is not None and (out.pairs is None or pair_of_corner.shape != (cloth.faces.shape[0], 9)):
        raise ValueError(f"pair blocks need pair_of_corner ({cloth.faces.shape[0]}, 9) int32 and a pairs buffer")
    outputs = [launch_arg(out.force[None], wp.vec3d), launch_arg(out.blocks[None], wp.mat33d),
               launch_arg(out.contact[None], wp.mat33d),
               launch_arg(idle.reshape(1, 1, 3).expand(1, 3, 3).contiguous() if out.pairs is None else out.pairs,
                          wp.mat33d)]
    return wp.launch(kernels["local_terms"], dim=dim, device=wp.device_from_torch(x.device), inputs=inputs,
                     outputs=outputs, record_cmd=True)


def zero_local_terms(num_verts: int, device: torch.device, num_pairs: int | None = None) -> LocalTerms:
    """Zeroed float64 buffers of a `LocalTerms` (with `num_pairs` pair blocks, or none)."""
    force, blocks, contact = (torch.zeros(num_verts, *shape, dtype=torch.float64, device=device)
                              for shape in ((3,), (3, 3), (3, 3)))
    pairs = None if num_pairs is None else torch.zeros(num_pairs, 3, 3, dtype=torch.float64, device=device)
    return LocalTerms(force, blocks, contact, pairs=pairs)


@torch.no_grad()
def vertex_blocks(x: Tensor, cloth: Cloth) -> Tensor:
    """3×3 diagonal blocks per vertex of the PSD majorant of ∇²(E_strain + E_bend) (module docstring).

    x (V, 3) [m] → (V, 3, 3) [N/m] in x's dtype, symmetric PSD. The strain part equals the
    diagonal blocks of `physics.hessians.strain_hessian` wherever every face's stress S is PSD;
    the bending part is Gauss–Newton. The local-terms kernel's blocks, without contact.
    """
    out = zero_local_terms(cloth.num_verts, x.device)
    x64 = x.detach().to(torch.float64).reshape(1, -1, 3).contiguous()
    part = (0, cloth.faces.shape[0], 0, cloth.hinges.shape[0], 0, cloth.num_verts)
    launch = record_local_terms(x64, cloth, out, part, external=None, corners=None, planes=None, stiffness=0.0,
                                margin=0.0, band=0.0)
    if launch is not None:
        with torch_stream(x.device):
            launch.launch()
    return out.blocks.to(x.dtype)


@torch.no_grad()
def compliance(blocks: Tensor, extra: Tensor | None = None, *, rel: float, tiny: float) -> Tensor:
    """Inverses of the regularised per-vertex stiffness blocks, (K_i + rel · max(tr K_i, tiny) · I)⁻¹
    with K_i = blocks (+ extra), each (V, 3, 3) [N/m] → (V, 3, 3) [m/N] float64. The floor relative to
    each vertex's own stiffness keeps K_i invertible (a vertex of an unstretched flat patch has a
    rank-deficient block); tiny: the stiffness floor of a vertex without any [N/m]."""
    blocks = blocks.detach().to(torch.float64).contiguous()
    if extra is not None:
        if tuple(extra.shape) != tuple(blocks.shape):
            raise ValueError(f"extra blocks must have shape {tuple(blocks.shape)}, got {tuple(extra.shape)}")
        extra = extra.detach().to(torch.float64).contiguous()
    out = torch.empty_like(blocks)
    launch = record_compliance(blocks, extra, out, rel=rel, tiny=tiny)
    if launch is not None:
        with torch_stream(blocks.device):
            launch.launch()
    return out


def record_compliance(blocks: Tensor, extra: Tensor | None, out: Tensor, *, rel: float, tiny: float):
    """The launch of `compliance` from float64 blocks (V, 3, 3) (+ extra) into `out`, recorded
    (`record_cmd`; None without vertices); the caller keeps the tensors alive while it is replayed."""
    if not blocks.shape[0]:
        return None
    wp = _kernels()["wp"]
    return wp.launch(_kernels()["compliance"], dim=blocks.shape[0], device=wp.device_from_torch(blocks.device),
                     inputs=[launch_arg(blocks, wp.mat33d), launch_arg(blocks if extra is None else extra, wp.mat33d),
                             int(extra is not None), float(rel), float(tiny)],
                     outputs=[launch_arg(out, wp.mat33d)], record_cmd=True)


@torch.no_grad()
def vertex_compliance(x: Tensor, cloth: Cloth, extra: Tensor | None = None, *, rel: float) -> Tensor:
    """`compliance` of `vertex_blocks` (+ extra (V, 3, 3) [N/m], e.g. the contact's), (V, 3, 3) [m/N]
    in x's dtype, computed in float64; tiny is the smallest normal number of x's dtype."""
    return compliance(vertex_blocks(x.to(torch.float64), cloth), extra, rel=rel,
                      tiny=float(torch.finfo(x.dtype).tiny)).to(x.dtype)


@torch.no_grad()
def pair_blocks(x: Tensor, cloth: Cloth, pair_of_corner: Tensor, num_pairs: int) -> Tensor:
    """The strain majorant's 3×3 blocks summed per vertex pair, (num_pairs, 3, 3) float64 [N/m].

    pair_of_corner (F, 9) int32, on x's device: for face f and corners a, b, the pair that face
    f's block (a, b) is added to (rows of vertex a, columns of vertex b), entry 3a + b. With
    ``arange(9 F)`` the result is every face's 9×9 block, laid out as (F, a, b, 3, 3). The
    local-terms kernel's (a solver forms them with a step's local terms,
    `physics.potential.GarmentPotential.local_terms`).
    """
    if pair_of_corner.shape != (cloth.faces.shape[0], 9) or pair_of_corner.dtype != torch.int32:
        raise ValueError(f"pair_of_corner must be int32 of shape ({cloth.faces.shape[0]}, 9), "
                         f"got {pair_of_corner.dtype} {tuple(pair_of_corner.shape)}")
    out = zero_local_terms(cloth.num_verts, x.device, num_pairs)
    x64 = x.detach().to(torch.float64).reshape(1, -1, 3).contiguous()
    launch = record_local_terms(x64, cloth, out, (0, cloth.faces.shape[0], 0, 0, 0, 0), external=None, corners=None,
                                planes=None, stiffness=0.0, margin=0.0, band=0.0,
                                pair_of_corner=pair_of_corner.contiguous())
    if launch is not None:
        with torch_stream(x.device):
            launch.launch()
    return out.pairs


def add_blocks(blocks: Tensor, rows: Tensor, add: Tensor) -> None:
    """blocks[rows[i]] += add[i], in place: blocks (P, 3, 3) float64, contiguous; rows (N,) int32 of
    distinct rows; add (N, 3, 3) float64 (the vertices' diagonal blocks into their pairs' blocks).
    One launch: torch's index_add_ of 3 × 3 blocks costs several times as much on the CPU."""
    if rows.dtype != torch.int32 or rows.shape[:1] != add.shape[:1] or not blocks.is_contiguous():
        raise ValueError(f"add_blocks needs contiguous blocks, int32 rows and one added block per row, got "
                         f"{'contiguous' if blocks.is_contiguous() else 'non-contiguous'} blocks, {rows.dtype} rows "
                         f"{tuple(rows.shape)} and blocks to add {tuple(add.shape)}")
    if rows.shape[0]:
        wp = _kernels()["wp"]
        with torch_stream(blocks.device):
            wp.launch(_kernels()["add_blocks"], dim=rows.shape[0], device=wp.device_from_torch(blocks.device),
                      inputs=[launch_arg(blocks, wp.mat33d), launch_arg(rows.contiguous(), wp.int32),
                              launch_arg(add.detach().contiguous(), wp.mat33d)])


def pair_product(blocks: Tensor, ends: Tensor, v: Tensor) -> Tensor:
    """K v of the matrix assembled from pair blocks (P, 3, 3) float64 [N/m], block p at rows of
    vertex ends[p, 0] and columns of vertex ends[p, 1] (ends (P, 2) int32), for a per-vertex field
    v (V, 3) float64: one launch, each pair adding its block's product into its row vertex.
    Differentiable in v (the backward applies Kᵀ); the blocks are constants."""
    return _PairProduct.apply(v, blocks, ends)


class _PairProduct(torch.autograd.Function):
    @staticmethod
    def forward(ctx, v: Tensor, blocks: Tensor, ends: Tensor) -> Tensor:
        ctx.save_for_backward(blocks, ends)
        return _pair_product(blocks, ends, v, transpose=False)

    @staticmethod
    def backward(ctx, grad: Tensor):
        blocks, ends = ctx.saved_tensors
        return _pair_product(blocks, ends, grad, transpose=True), None, None


def _pair_product(blocks: Tensor, ends: Tensor, v: Tensor, *, transpose: bool) -> Tensor:
    wp = _kernels()["wp"]
    v = v.detach().contiguous()
    out = torch.zeros_like(v)
    if blocks.shape[0]:
        with torch_stream(v.device):
            wp.launch(_kernels()["pair_product"], dim=blocks.shape[0], device=wp.device_from_torch(v.device),
                      inputs=[launch_arg(blocks.detach().contiguous(), wp.mat33d), launch_arg(ends, wp.int32),
                              launch_arg(v, wp.vec3d), int(transpose)], outputs=[launch_arg(out, wp.vec3d)])
    return out

"""The coarse level of a two-level preconditioner: a Galerkin correction on smooth patches.

Block Jacobi (`physics.hessians.vertex_blocks`) relaxes a garment's short wavelengths at once and
its long ones — the garment sliding down or riding up as a whole, a strap stretching along its
length — over many steps: such a motion barely strains any face, but each vertex sees only its
own stiffness, through which the weak force that drives the motion (gravity) moves it by a tiny
step, so a garment can stay centimetres above where it hangs at equilibrium. The coarse level
adds the motions of a few hundred smooth patches per garment, solved together:

    z_c = P (Pᵀ K P)⁻¹ Pᵀ r,

with K the PSD strain-Hessian majorant of every face (`physics.majorant.pair_blocks`), the
solver's per-vertex blocks (contact, grip and the links' diagonal blocks,
`physics.forces.extra_blocks`) and the links' coupling (the off-diagonal blocks −H of the
stitches' and layer pairs' majorant [[H, −H], [−H, H]], `physics.forces.links`), and P a
smoothed-aggregation prolongation (`topology.aggregates`, `topology.smoothed_prolongation`):
patch indicators averaged over mesh neighbours, so a patch moves as a smooth bump and no kink is
left at its border (raw indicators leave kinks that the fine level then has to bend out). The
links' coupling matters for a multi-piece garment: without it a stitched or layered vertex's H
acts in the coarse space as a spring to a fixed point, and the pieces cannot slide together over
the body; with it only their relative motion is stiff. Bending is left out of Pᵀ K P: smooth
patches barely bend, and its hinge blocks (16 vertex pairs each) would more than double the
gather for little change in the correction.

Numerics: patches and P depend on a garment's topology only and are cached. K (in the cloth's
dtype) is gathered into 3×3 blocks of the vertex pairs that share a face or a link. Pᵀ K P is
linear in those blocks: its 3×3 block (I, J) is Σ P[i, I] P[j, J] K_ij over the pairs (i, j), so
a garment's topology and links fix a sparse Galerkin operator G (coarse blocks × pairs), built
once and cached, and each `factor` forms Pᵀ K P as the product G · K in float64, one launch for
all the batch's garments of that topology, written straight into each garment's coarse matrix
(`physics.galerkin`), which is then factorised by Cholesky (`physics.coarse_factor`). A patch
couples only to the patches near it, and the patches are numbered (the narrowest of several
reverse Cuthill–McKee orderings, `topology.narrow_band_order`) so that those couplings lie in a
band about the diagonal: on the CPU the matrix is assembled and factorised in band storage
(LAPACK's pbtrf and pbtrs: for a band w wide, n w² operations instead of n³/3), on CUDA dense
(cuSOLVER), where a few hundred unknowns cost little either way and the garments of one topology
(a batch of one garment on many bodies) are factorised and solved together, in one batched call
each. The correction is differentiable in r (P and the factor are constants). The factor keeps
K's pair blocks, so that `stiffness_product` applies K itself (the solver's inner iterations on
the quadratic model, `model.stretching_solver`).

Devices: everything runs on the cloth's device (CPU or CUDA): the pair blocks (a Warp kernel),
the Galerkin product, the factorisation (each garment's coarse system is small, at most
3·MAX_PATCHES unknowns) and the correction `solve` (every solver step), with P, G and the
factors held there (the band factors as NumPy arrays).
"""

from __future__ import annotations

import collections
import threading
import warnings
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from torch import Tensor

from physdrape.geometry import topology
from physdrape.physics.cloth import Cloth
from physdrape.physics.coarse_factor import (
    BandSolve,
    regularized_band_cholesky,
    regularized_cholesky,
)
from physdrape.physics.forces import links
from physdrape.physics.galerkin import GalerkinProduct
from physdrape.physics.majorant import add_blocks, pair_product
from physdrape.physics.majorant import pair_blocks as majorant_pair_blocks
from physdrape.threads import one_blas_thread

__all__ = ["CoarseSpace"]

#: Most patches of one garment: a larger garment gets more coarsening levels, so that its coarse
#: factor stays small (1,200 patches: 3,600 unknowns per refresh, in a band).
MAX_PATCHES = 1200

def _garment_prolongation(faces: np.ndarray, num_verts: int, levels: int, smoothing: int) -> sp.csr_matrix:
    """P (V, patches) of one garment (local vertex ids); `levels` is raised until the garment has
    at most MAX_PATCHES patches (or coarsening stops gaining)."""
    edges = topology.undirected_edges(faces)
    label = topology.aggregates(edges, num_verts, levels)
    while label.max(initial=0) + 1 > MAX_PATCHES:
        levels += 1
        coarser = topology.aggregates(edges, num_verts, levels)
        if coarser.max() >= label.max():
            break
        label = coarser
    return topology.smoothed_prolongation(edges, num_verts, label, smoothing)


def _band_order(blocks: np.ndarray, patches: int) -> np.ndarray:
    """A numbering of the patches (new → old) under which the coarse blocks (keys I · patches + J)
    lie close to the diagonal (`topology.narrow_band_order`)."""
    return topology.narrow_band_order(blocks // patches, blocks % patches, patches)


def _galerkin_operator(prolong: sp.csr_matrix, rows: np.ndarray, cols: np.ndarray) -> tuple[sp.csr_matrix, np.ndarray]:
    """The sparse operator G with (Pᵀ K P)_IJ = Σ_p G[(I, J), p] K_p for K given as blocks K_p of
    the vertex pairs p = (rows[p], cols[p]): G[(I, J), p] = P[rows[p], I] · P[cols[p], J].

    Returns G, one row per coarse block (I, J) that some pair reaches (scipy CSR, (blocks,
    pairs)), and those blocks' keys I · patches + J, ascending (the order of G's rows)."""
    patches = prolong.shape[1]
    row_counts = np.diff(prolong.indptr)
    count_a, count_b = row_counts[rows], row_counts[cols]
    per_pair = count_a * count_b  # every patch of the row vertex against every patch of the column vertex
    pair = np.repeat(np.arange(len(rows)), per_pair)
    local = np.arange(per_pair.sum()) - np.repeat(np.cumsum(per_pair) - per_pair, per_pair)
    entry_a = prolong.indptr[rows][pair] + local // count_b[pair]
    entry_b = prolong.indptr[cols][pair] + local % count_b[pair]
    keys = prolong.indices[entry_a].astype(np.int64) * patches + prolong.indices[entry_b]
    # the distinct keys in ascending order and each key's place among them (np.unique's, by a
    # table over the patches² keys instead of a sort of the many products)
    reached = np.zeros(patches * patches, dtype=bool)
    reached[keys] = True
    blocks = np.flatnonzero(reached)
    place = np.cumsum(reached) - 1
    row = place[keys]
    weights = prolong.data[entry_a] * prolong.data[entry_b]
    operator = sp.csr_matrix((weights, (row.reshape(-1), pair)), shape=(len(blocks), len(rows)))
    operator.sum_duplicates()
    return operator, blocks


def _vertex_pairs(faces: np.ndarray, num_verts: int,
                  linked: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The vertex pairs (a, b) that share a face or a link (`linked` (L, 2), both orders), as keys
    a · num_verts + b, ascending; the pair of each face's corner pair (F, 9), entry 3 i + j for
    corners i, j; and the pairs (a, b) and (b, a) of each link (L, 2)."""
    corner = np.repeat(faces, 3, axis=1).reshape(-1).astype(np.int64) * num_verts + np.tile(faces, (1, 3)).reshape(-1)
    link = np.stack([linked[:, 0] * num_verts + linked[:, 1], linked[:, 1] * num_verts + linked[:, 0]], axis=1)
    pairs, where = np.unique(np.concatenate([corner, link.reshape(-1)]), return_inverse=True)
    where = where.reshape(-1)
    return pairs, where[:len(corner)].reshape(-1, 9), where[len(corner):].reshape(-1, 2)


@dataclass(frozen=True)
class _GarmentGalerkin:
    """One garment topology's coarse space: P (V, patches), its patches numbered so that the coarse
    matrix is banded (`_band_order`), its vertex pairs (the pair of each face's corner pair (F, 9),
    of each vertex with itself (V,) and of each link both ways (L, 2), numbered in ascending key
    order), its Galerkin operator G (coarse blocks, pairs), where each entry (a, b) of each coarse
    block (I, J) goes in its dense coarse matrix, row-major: (3 I + a) · 3 patches + 3 J + b, and
    that matrix's half-bandwidth."""

    prolong: sp.csr_matrix
    num_pairs: int
    pair_ends: np.ndarray  # (pairs, 2): each pair's two vertices, local ids
    pair_of_corner: np.ndarray
    pair_of_vertex: np.ndarray
    pair_of_link: np.ndarray
    operator: sp.csr_matrix
    destination: np.ndarray
    bandwidth: int  # entries (r, c) of the coarse matrix with |r − c| > bandwidth are zero


#: Garment coarse spaces by topology, the most recently used kept (G of a 3k-vertex garment is
#: about 4 MB: a training set's garments fit, a long run over more only rebuilds some).
_GALERKIN: collections.OrderedDict[tuple, _GarmentGalerkin] = collections.OrderedDict()
_GALERKIN_SIZE = 128

#: Guards `_GALERKIN` and `_STRUCTURES` (batches draped on parallel threads share them); held
#: while a missing entry is built, so that each is built once.
_CACHE_LOCK = threading.RLock()


def _garment_galerkin(faces: np.ndarray, num_verts: int, linked: np.ndarray, levels: int,
                      smoothing: int) -> _GarmentGalerkin:
    """The coarse space of one garment (local vertex ids; links (L, 2)), cached by topology and links."""
    key = (topology.digest(faces), faces.shape[0], topology.digest(linked), num_verts, levels, smoothing)
    with _CACHE_LOCK:
        if key not in _GALERKIN:
            prolong = _garment_prolongation(faces, num_verts, levels, smoothing)
            pairs, where, link_pairs = _vertex_pairs(faces, num_verts, linked)
            itself = np.searchsorted(pairs, np.arange(num_verts, dtype=np.int64) * (num_verts + 1))
            operator, blocks = _galerkin_operator(prolong, pairs // num_verts, pairs % num_verts)
            patches = prolong.shape[1]
            # patches renumbered so that the coarse matrix is banded (the correction does not
            # depend on their numbering): G's row of block (I, J) is that of (new I, new J)
            order = _band_order(blocks, patches)
            new = np.empty_like(order)
            new[order] = np.arange(patches)
            prolong = prolong[:, order].tocsr()
            blocks = new[blocks // patches] * patches + new[blocks % patches]
            bandwidth = 3 * int(np.abs(blocks // patches - blocks % patches).max(initial=0)) + 2
            row = 3 * (blocks // patches)[:, None] + np.arange(3)  # (blocks, 3)
            col = 3 * (blocks % patches)[:, None] + np.arange(3)
            destination = (row[:, :, None] * (3 * patches) + col[:, None, :]).reshape(-1)
            _GALERKIN[key] = _GarmentGalerkin(prolong, len(pairs), np.stack([pairs // num_verts, pairs % num_verts], 1),
                                              where.astype(np.int32), itself, link_pairs, operator, destination,
                                              min(bandwidth, 3 * patches - 1))
            while len(_GALERKIN) > _GALERKIN_SIZE:
                _GALERKIN.popitem(last=False)
        _GALERKIN.move_to_end(key)
        return _GALERKIN[key]


def _sparse_csr(matrix: sp.csr_matrix, device: torch.device) -> Tensor:
    """A scipy CSR matrix as a float64 torch sparse CSR tensor on `device` (torch's CSR matrix
    product is its fastest sparse-dense one on the CPU and runs on CUDA)."""
    with warnings.catch_warnings():  # torch flags its CSR layout as beta on first use; it is what we need
        warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
        return torch.sparse_csr_tensor(torch.from_numpy(matrix.indptr.astype(np.int64)).to(device),
                                       torch.from_numpy(matrix.indices.astype(np.int64)).to(device),
                                       torch.from_numpy(matrix.data.astype(np.float64)).to(device), size=matrix.shape,
                                       device=device, check_invariants=True)


@dataclass(frozen=True)
class _Group:
    """The garments of a batch that share one topology, formed together: the Galerkin product
    that writes their coarse blocks into their matrices, each garment's coarse dofs (garments, n),
    and in dense storage the buffer index of each garment's matrix (garments, n²), factorised and
    solved together."""

    galerkin: GalerkinProduct
    coarse_dofs: Tensor
    matrix_entries: Tensor | None


@dataclass(frozen=True)
class _BatchStructure:
    """What a packed batch's coarse space keeps of its topology, on the cloth's device: P and Pᵀ
    (sparse CSR, float64), where each face's corner-pair blocks of K go and each link's (both
    ways, in the order of `physics.forces.links`), the Galerkin operator of each distinct garment
    topology with where its products go in the garments' coarse matrices (one flat buffer,
    garment after garment; in band storage where `banded`), and each garment's coarse dofs and
    place in that buffer."""

    num_patches: int
    coarse_ranges: list[tuple[int, int]]  # coarse dofs [c0, c1) of each garment
    matrix_offsets: list[int]  # where each garment's coarse matrix (dense or band) starts in the buffer
    buffer_size: int  # all garments' coarse matrices
    num_pairs: int
    pair_ends: Tensor  # (pairs, 2) vertex indices of the batch
    pair_of_corner: Tensor
    pair_of_vertex: Tensor
    pair_of_link: Tensor  # (L, 2)
    groups: list[_Group]
    prolong: Tensor  # P, sparse CSR (V, patches)
    restrict: Tensor  # Pᵀ, sparse CSR (patches, V)
    banded: bool  # the buffer holds each garment's band (n, w + 1), band[j, k] = A[j + k, j], not A
    band_widths: list[int]  # w of each garment

    @staticmethod
    def build(faces: np.ndarray, vert_counts: tuple[int, ...], face_counts: tuple[int, ...], linked: np.ndarray,
              levels: int, smoothing: int, device: torch.device, banded: bool) -> _BatchStructure:
        garments, coarse_ranges, matrix_offsets, pair_starts = [], [], [], []
        v0, f0, c0, offset, p0 = 0, 0, 0, 0, 0
        starts = np.cumsum((0, *vert_counts))
        link_garment = np.searchsorted(starts, linked, side="right") - 1  # (L, 2)
        if (link_garment[:, 0] != link_garment[:, 1]).any():
            raise ValueError("CoarseSpace: a stitch or layer pair ties two garments; links must join vertices of "
                             "one garment")
        pair_of_link = np.zeros(linked.shape, np.int64)
        ends = []
        for g, (nv, nf) in enumerate(zip(vert_counts, face_counts)):
            local = faces[f0:f0 + nf] - v0
            if nf and (local.min() < 0 or local.max() >= nv):
                raise ValueError("CoarseSpace needs each garment's vertices and faces packed contiguously")
            own = np.flatnonzero(link_garment[:, 0] == g)
            garment = _garment_galerkin(np.ascontiguousarray(local), nv, linked[own] - v0, levels, smoothing)
            pair_of_link[own] = garment.pair_of_link + p0
            ends.append(garment.pair_ends + v0)
            garments.append(garment)
            patches = garment.prolong.shape[1]
            coarse_ranges.append((3 * c0, 3 * (c0 + patches)))
            matrix_offsets.append(offset)
            pair_starts.append(p0)  # the batch numbers its pairs garment after garment
            c0, offset, p0 = c0 + patches, offset + (3 * patches) ** 2, p0 + garment.num_pairs
            v0, f0 = v0 + nv, f0 + nf
        # The buffer holds each garment's band (garment after garment; the upper triangle is not
        # stored) or its dense matrix.
        widths = [g.bandwidth for g in garments]
        if banded:
            sizes = [(b - a) * (w + 1) for (a, b), w in zip(coarse_ranges, widths)]
            matrix_offsets = np.cumsum([0, *sizes[:-1]]).tolist() if sizes else []
            offset = int(sum(sizes))
        members: dict[int, list[int]] = {}
        for g, garment in enumerate(garments):
            members.setdefault(id(garment), []).append(g)
        groups = []
        for indices in members.values():
            garment = garments[indices[0]]
            local = garment.destination
            if banded:
                n = 3 * garment.prolong.shape[1]
                r, c = local // n, local % n
                local = np.where(r >= c, c * (garment.bandwidth + 1) + (r - c), -1)
            destination = np.array([matrix_offsets[g] for g in indices], dtype=np.int64)[:, None] + local
            destination[:, local < 0] = -1
            n = 3 * garment.prolong.shape[1]
            dofs = np.array([coarse_ranges[g][0] for g in indices], dtype=np.int64)[:, None] + np.arange(n)
            entries = None if banded else torch.from_numpy(
                np.array([matrix_offsets[g] for g in indices], dtype=np.int64)[:, None] + np.arange(n * n)).to(device)
            starts = np.array([pair_starts[g] for g in indices])
            groups.append(_Group(GalerkinProduct(garment.operator, starts, destination, device),
                                 torch.from_numpy(dofs).to(device), entries))
        prolong = sp.block_diag([g.prolong for g in garments], format="csr")  # (V, patches)
        return _BatchStructure(
            num_patches=prolong.shape[1],
            coarse_ranges=coarse_ranges,
            matrix_offsets=matrix_offsets,
            buffer_size=offset,
            num_pairs=p0,
            pair_ends=torch.from_numpy(np.concatenate(ends) if ends else np.zeros((0, 2), np.int64)).to(device),
            pair_of_corner=torch.from_numpy(np.concatenate(
                [g.pair_of_corner + start for g, start in zip(garments, pair_starts)]).astype(np.int32)).to(device),
            pair_of_vertex=torch.from_numpy(np.concatenate(
                [g.pair_of_vertex + start for g, start in zip(garments, pair_starts)]).astype(np.int32)).to(device),
            pair_of_link=torch.from_numpy(pair_of_link).to(device),
            groups=groups,
            prolong=_sparse_csr(prolong, device),
            restrict=_sparse_csr(prolong.T.tocsr(), device),
            banded=banded,
            band_widths=widths,
        )


#: Batch structures by topology (a drape of the same garments reuses its batch's structure).
_STRUCTURES: collections.OrderedDict[tuple, _BatchStructure] = collections.OrderedDict()
_STRUCTURES_SIZE = 16


class CoarseSpace:
    """Smoothed-aggregation coarse space of a packed garment batch (module docstring).

    Args:
        cloth: the batch (garments packed contiguously, as `GarmentBatch.pack` does), on any device.
        levels: patch seeds are the nodes of `topology.coarse_graphs` level `levels` (2: patches
            of 6–15 vertices).
        smoothing: neighbour-averaging passes of the patch indicators.
        layer_slide: the layer pairs' tangential share β in K (`physics.forces.links`; None: the
            solver's `LAYER_SLIDE_DAMPING`).
    """

    def __init__(self, cloth: Cloth, *, levels: int = 2, smoothing: int = 2, layer_slide: float | None = None) -> None:
        if levels < 1 or smoothing < 0:
            raise ValueError(f"need levels ≥ 1 and smoothing ≥ 0, got levels={levels}, smoothing={smoothing}")
        self.cloth = cloth
        faces = cloth.faces.cpu().numpy()
        vert_counts = tuple(torch.bincount(cloth.vert_garment, minlength=cloth.num_garments).tolist())
        face_counts = tuple(torch.bincount(cloth.face_garment, minlength=cloth.num_garments).tolist())
        self._links = links(cloth, slide=layer_slide)
        linked = np.zeros((0, 2), np.int64) if self._links is None else self._links.pairs.cpu().numpy()
        key = (topology.digest(faces), faces.shape[0], topology.digest(linked), vert_counts, face_counts, levels,
               smoothing, str(cloth.device))
        with _CACHE_LOCK:
            if key not in _STRUCTURES:
                # the CPU factorises each garment's band (LAPACK), CUDA its dense matrix (cuSOLVER)
                _STRUCTURES[key] = _BatchStructure.build(faces, vert_counts, face_counts, linked, levels, smoothing,
                                                         cloth.device, banded=cloth.device.type == "cpu")
                while len(_STRUCTURES) > _STRUCTURES_SIZE:
                    _STRUCTURES.popitem(last=False)
            _STRUCTURES.move_to_end(key)
            self._s = _STRUCTURES[key]
        self.num_patches = self._s.num_patches
        self._factors: list | None = None  # band: one per garment (NumPy); dense: (count, n, n) per group
        self._gram: list[Tensor] | None = None
        self.blocks: Tensor | None = None  # K at the last `factor`: a 3 × 3 block per vertex pair, float64
        self._buffer: Tensor | None = None
        self._ends32: Tensor | None = None  # the pairs' vertices, int32 (what the product kernel reads)

    @property
    def pair_layout(self) -> tuple[Tensor, int]:
        """Where each face's corner-pair blocks go among the vertex pairs (pair_of_corner (F, 9)
        int32) and how many pairs there are: what `physics.majorant.pair_blocks` forms K's blocks in."""
        return self._s.pair_of_corner, self._s.num_pairs

    def factor(self, x: Tensor, vertex_blocks: Tensor | None = None, pair_blocks: Tensor | None = None,
               link_weight: Tensor | None = None) -> None:
        """Form and factorise Pᵀ K P at positions x (V, 3); vertex_blocks (V, 3, 3): the diagonal
        blocks added to the strain majorant's (the solver's contact blocks and
        `physics.forces.extra_blocks`), or None. The cloth's links add their coupling −H between
        the two vertices of each link; their diagonal blocks H are part of `extra_blocks`, which
        vertex_blocks must then include for K to be PSD. pair_blocks: the strain majorant's pair
        blocks at x in `pair_layout` (a solver forms them with its step's local terms), or None
        (formed here); float64 pair blocks are a scratch buffer: K's blocks are formed in them in
        place (the solver forms them again before their next use). link_weight: each link's factor
        (L,) (`physics.forces.layer_link_weights`; the diagonal blocks in vertex_blocks must carry
        the same), or None: all 1."""
        s = self._s
        with torch.no_grad():
            if pair_blocks is None:
                pair_blocks = majorant_pair_blocks(x, self.cloth, s.pair_of_corner, s.num_pairs)
            blocks = pair_blocks.to(torch.float64).contiguous()
            if vertex_blocks is not None:
                add_blocks(blocks, s.pair_of_vertex, vertex_blocks.detach().to(blocks.dtype))
            if self._links is not None:
                coupling = -self._links.blocks.to(blocks.dtype)
                if link_weight is not None:
                    coupling = coupling * link_weight.to(blocks.dtype)[:, None, None]
                blocks.index_add_(0, s.pair_of_link[:, 0], coupling).index_add_(0, s.pair_of_link[:, 1], coupling)
            self.blocks = blocks
            if self._buffer is None:  # the coarse matrices' storage, formed again at each factorisation
                self._buffer = blocks.new_zeros(s.buffer_size)
            else:
                self._buffer.zero_()
            buffer = self._buffer
            for group in s.groups:  # Pᵀ K P: G times the pair blocks of the group's garments
                group.galerkin(blocks, buffer)
        if s.banded:
            with one_blas_thread():
                self._factors = [
                    regularized_band_cholesky(buffer[start:start + (c1 - c0) * (w + 1)].view(c1 - c0, w + 1))
                    for start, (c0, c1), w in zip(s.matrix_offsets, s.coarse_ranges, s.band_widths)]
        else:  # the garments of one topology together: one batched factorisation per group
            self._factors = [regularized_cholesky(buffer[group.matrix_entries].view(-1, n, n))
                             for group in s.groups for n in [group.coarse_dofs.shape[1]]]

    def stiffness_product(self, v: Tensor) -> Tensor:
        """K v for a per-vertex field v (V, 3), K the fine-level stiffness that the last `factor`
        projected (the strain majorant, its vertex blocks and the links' coupling), in v's dtype;
        differentiable in v (K is a constant)."""
        if self.blocks is None:
            raise RuntimeError("CoarseSpace.stiffness_product before factor: call factor(x) first")
        if self._ends32 is None:
            self._ends32 = self._s.pair_ends.to(torch.int32).contiguous()
        return pair_product(self.blocks, self._ends32, v.double()).to(v.dtype)

    def fit(self, field: Tensor) -> Tensor:
        """The coarse space's least-squares fit of a per-vertex field (V, 3): P c with c minimising
        ‖P c − field‖² garment by garment (P (PᵀP)⁻¹ Pᵀ field); differentiable in the field."""
        s = self._s
        if self._gram is None:  # each garment's PᵀP (block diagonal in P's columns), factorised once
            prolong = sp.csr_matrix((s.prolong.values().cpu().numpy(), s.prolong.col_indices().cpu().numpy(),
                                     s.prolong.crow_indices().cpu().numpy()), shape=tuple(s.prolong.shape))
            gram = (prolong.T @ prolong).tocsc()
            self._gram = [torch.linalg.cholesky(torch.from_numpy(gram[c0 // 3:c1 // 3, c0 // 3:c1 // 3].toarray())
                                                .to(s.prolong.device))
                          for c0, c1 in s.coarse_ranges]
        coarse = s.restrict @ field.double()
        coarse = torch.cat([torch.cholesky_solve(coarse[c0 // 3:c1 // 3], chol)
                            for (c0, c1), chol in zip(s.coarse_ranges, self._gram)])
        return (s.prolong @ coarse).to(field.dtype)

    def solve(self, r: Tensor) -> Tensor:
        """P (Pᵀ K P)⁻¹ Pᵀ r for forces r (V, 3) [N] → displacements (V, 3) [m]; needs `factor`."""
        if self._factors is None:
            raise RuntimeError("CoarseSpace.solve before factor: call factor(x) first")
        s = self._s
        coarse_r = (s.restrict @ r.double()).reshape(-1, 1)
        if s.banded:
            coarse_z = BandSolve.apply(coarse_r, self._factors, s.coarse_ranges)
            return (s.prolong @ coarse_z.reshape(self.num_patches, 3)).to(r.dtype)
        coarse_z = torch.zeros_like(coarse_r)
        for group, chol in zip(s.groups, self._factors):  # (L Lᵀ)⁻¹ b, the group's garments together
            dofs = group.coarse_dofs.reshape(-1)
            solved = torch.cholesky_solve(coarse_r[dofs].view(*group.coarse_dofs.shape, 1), chol)
            coarse_z = coarse_z.index_copy(0, dofs, solved.reshape(-1, 1))
        return (s.prolong @ coarse_z.reshape(self.num_patches, 3)).to(r.dtype)

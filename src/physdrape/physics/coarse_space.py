"""The coarse level of a two-level preconditioner: a Galerkin correction on smooth patches.

Block Jacobi (`physics.hessians.vertex_blocks`) relaxes a garment's short wavelengths at once and
its long ones — the garment sliding down or riding up as a whole, a strap stretching along its
length — over many steps: such a motion barely strains any face, but each vertex sees only its
own stiffness, through which the weak force that drives the motion (gravity) moves it by a tiny
step, so a garment can stay centimetres above where it hangs at equilibrium. The coarse level
adds the motions of a few hundred smooth patches per garment, solved together:

    z_c = P (Pᵀ K P)⁻¹ Pᵀ r,

with K the PSD strain-Hessian majorant of every face (`physics.majorant.pair_blocks`) plus the
solver's contact blocks, and P a smoothed-aggregation prolongation (`topology.aggregates`,
`topology.smoothed_prolongation`): patch indicators averaged over mesh neighbours, so a patch
moves as a smooth bump and no kink is left at its border (raw indicators leave kinks that the
fine level then has to bend out). Bending is left out of Pᵀ K P: smooth patches barely bend,
and its hinge blocks (16 vertex pairs each) would more than double the gather for little change
in the correction.

Numerics: patches and P depend on a garment's topology only and are cached. K (in the cloth's
dtype) is gathered into 3×3 blocks of the vertex pairs that share a face; Pᵀ K P is formed in
float64 with scipy (block-sparse products) and factorised per garment (dense Cholesky). The
correction is differentiable in r (P and the factor are constants).

Devices: the blocks of K are summed per vertex pair on the cloth's device (a Warp kernel), and
the correction `solve` (every solver step) runs there too, with P and the factors held there. The
Galerkin product and the factorisation (`factor`, every few steps) run on the host: Pᵀ K P is a
product of block-sparse matrices whose pattern is fixed by the topology, which scipy forms in
float64 at once, and each garment's coarse system is small (at most 3·MAX_PATCHES unknowns). Each
`factor` therefore copies the pair and contact blocks to the host and the factors back; on the
CPU both copies are free.
"""

from __future__ import annotations

import collections
import hashlib
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import torch
from torch import Tensor

from physdrape.geometry import topology
from physdrape.physics.cloth import Cloth
from physdrape.physics.majorant import pair_blocks

__all__ = ["CoarseSpace"]

#: Regularisation of Pᵀ K P relative to its mean diagonal (a garment the contact does not pin);
#: raised ×100 until the factorisation succeeds.
REGULARIZATION = 1e-6

#: Most patches of one garment: a larger garment gets more coarsening levels, so that its dense
#: coarse factor stays small (600 patches: an 1,800 × 1,800 Cholesky per refresh).
MAX_PATCHES = 600

_CACHE: dict[tuple, sp.csr_matrix] = {}
_CACHE_SIZE = 1024


def _garment_prolongation(faces: np.ndarray, num_verts: int, levels: int, smoothing: int) -> sp.csr_matrix:
    """P (V, patches) of one garment (local vertex ids), cached by topology; `levels` is raised
    until the garment has at most MAX_PATCHES patches (or coarsening stops gaining)."""
    key = (hashlib.blake2b(faces.tobytes(), digest_size=16).digest(), faces.shape[0], num_verts, levels, smoothing)
    if key not in _CACHE:
        if len(_CACHE) >= _CACHE_SIZE:
            _CACHE.clear()
        edges = topology.undirected_edges(faces)
        label = topology.aggregates(edges, num_verts, levels)
        while label.max(initial=0) + 1 > MAX_PATCHES:
            levels += 1
            coarser = topology.aggregates(edges, num_verts, levels)
            if coarser.max() >= label.max():
                break
            label = coarser
        _CACHE[key] = topology.smoothed_prolongation(edges, num_verts, label, smoothing)
    return _CACHE[key]


def _regularized_cholesky(block: Tensor) -> Tensor:
    """Cholesky factor of block + r·mean(diag)·I, r = REGULARIZATION, raised ×100 until it factorises
    (a float32 K rounds its near-null rigid modes to slightly negative). A block without stiffness
    (a garment of one patch, free of the body, moves rigidly at no cost) is regularised with
    mean(diag) = 1: its correction is then a long rigid move that the solver's step clip and line
    search shorten like any other. `block` is a scratch copy: its diagonal is overwritten."""
    if not bool(torch.isfinite(block.sum())):  # a sum is finite only if every entry is
        raise ValueError("CoarseSpace.factor: the stiffness has NaN/inf entries (non-finite positions?)")
    diagonal = block.diagonal()
    original = diagonal.clone()
    scale = original.mean()
    if not bool(scale > 0):  # no stiffness at all (a lone patch moving freely): any scale regularises it
        scale = torch.ones((), dtype=block.dtype, device=block.device)
    for attempt in range(4):  # up to REGULARIZATION × 10⁶ = the mean diagonal itself
        diagonal.copy_(original + REGULARIZATION * 100.0 ** attempt * scale)
        chol, info = torch.linalg.cholesky_ex(block)
        if int(info) == 0:
            return chol
    raise ValueError("CoarseSpace.factor: the coarse stiffness is not positive semi-definite even with a "
                     "regularisation of its mean diagonal (K must be a PSD majorant)")


@dataclass(frozen=True)
class _BatchStructure:
    """What a packed batch's coarse space keeps of its topology: P (as 3×3 blocks, and as COO
    rows, columns and weights on the cloth's device), each garment's coarse dofs, and where each
    face's corner-pair blocks of K go."""

    num_patches: int
    coarse_ranges: list[tuple[int, int]]  # coarse dofs [c0, c1) of each garment
    p3: sp.bsr_matrix
    p3_t: sp.bsr_matrix
    pair_cols: np.ndarray
    pair_indptr: np.ndarray
    pair_of_corner: Tensor
    pair_of_vertex: Tensor
    rows: Tensor
    cols: Tensor
    weights: Tensor

    @staticmethod
    def build(faces: np.ndarray, vert_counts: tuple[int, ...], face_counts: tuple[int, ...], levels: int,
              smoothing: int, device: torch.device) -> _BatchStructure:
        parts, coarse_ranges, v0, f0, c0 = [], [], 0, 0, 0
        for nv, nf in zip(vert_counts, face_counts):
            local = faces[f0:f0 + nf] - v0
            if nf and (local.min() < 0 or local.max() >= nv):
                raise ValueError("CoarseSpace needs each garment's vertices and faces packed contiguously")
            part = _garment_prolongation(np.ascontiguousarray(local), nv, levels, smoothing)
            parts.append(part)
            coarse_ranges.append((3 * c0, 3 * (c0 + part.shape[1])))
            c0 += part.shape[1]
            v0, f0 = v0 + nv, f0 + nf
        prolong = sp.block_diag(parts, format="csr")  # (V, patches)
        p3 = sp.kron(prolong, sp.identity(3), format="csr")  # (3V, 3·patches), dof 3·v + axis
        # K as 3×3 blocks of the vertex pairs that share a face: where each face-corner pair goes
        num_verts = sum(vert_counts)
        key = np.repeat(faces, 3, axis=1).reshape(-1).astype(np.int64) * num_verts + np.tile(faces, (1, 3)).reshape(-1)
        pairs, where = np.unique(key, return_inverse=True)
        coo = prolong.tocoo()
        return _BatchStructure(
            num_patches=prolong.shape[1],
            coarse_ranges=coarse_ranges,
            p3=p3.tobsr(blocksize=(3, 3)),
            p3_t=p3.T.tobsr(blocksize=(3, 3)),
            pair_cols=(pairs % num_verts).astype(np.int32),
            pair_indptr=np.concatenate([[0], np.cumsum(np.bincount(pairs // num_verts, minlength=num_verts))]),
            pair_of_corner=torch.from_numpy(where.astype(np.int32).reshape(-1, 9)).to(device),
            pair_of_vertex=torch.from_numpy(np.searchsorted(pairs, np.arange(num_verts, dtype=np.int64) * (num_verts + 1))),
            rows=torch.from_numpy(coo.row.astype(np.int64)).to(device),
            cols=torch.from_numpy(coo.col.astype(np.int64)).to(device),
            weights=torch.from_numpy(coo.data).to(device=device, dtype=torch.float64),
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
    """

    def __init__(self, cloth: Cloth, *, levels: int = 2, smoothing: int = 2) -> None:
        if levels < 1 or smoothing < 0:
            raise ValueError(f"need levels ≥ 1 and smoothing ≥ 0, got levels={levels}, smoothing={smoothing}")
        self.cloth = cloth
        faces = cloth.faces.cpu().numpy()
        vert_counts = tuple(torch.bincount(cloth.vert_garment, minlength=cloth.num_garments).tolist())
        face_counts = tuple(torch.bincount(cloth.face_garment, minlength=cloth.num_garments).tolist())
        key = (hashlib.blake2b(faces.tobytes(), digest_size=16).digest(), faces.shape[0], vert_counts, face_counts,
               levels, smoothing, str(cloth.device))
        if key not in _STRUCTURES:
            _STRUCTURES[key] = _BatchStructure.build(faces, vert_counts, face_counts, levels, smoothing, cloth.device)
            while len(_STRUCTURES) > _STRUCTURES_SIZE:
                _STRUCTURES.popitem(last=False)
        _STRUCTURES.move_to_end(key)
        self._s = _STRUCTURES[key]
        self.num_patches = self._s.num_patches
        self._factors: list[Tensor] | None = None

    def factor(self, x: Tensor, vertex_blocks: Tensor | None = None) -> None:
        """Form and factorise Pᵀ K P at positions x (V, 3); vertex_blocks (V, 3, 3): extra
        per-vertex stiffness added to K (the solver's contact blocks), or None."""
        with torch.no_grad():
            blocks = pair_blocks(x, self.cloth, self._s.pair_of_corner, len(self._s.pair_cols))
            blocks = blocks.cpu()  # the Galerkin product is formed on the host (module docstring)
            if vertex_blocks is not None:
                blocks.index_add_(0, self._s.pair_of_vertex, vertex_blocks.detach().double().cpu())
        n = 3 * self.cloth.num_verts
        stiffness = sp.bsr_matrix((blocks.numpy(), self._s.pair_cols, self._s.pair_indptr), shape=(n, n))
        coarse = (self._s.p3_t @ (stiffness @ self._s.p3)).tocsr()
        device = self.cloth.device
        self._factors = [_regularized_cholesky(torch.from_numpy(coarse[c0:c1, c0:c1].toarray())).to(device)
                         for c0, c1 in self._s.coarse_ranges]

    def solve(self, r: Tensor) -> Tensor:
        """P (Pᵀ K P)⁻¹ Pᵀ r for forces r (V, 3) [N] → displacements (V, 3) [m]; needs `factor`."""
        if self._factors is None:
            raise RuntimeError("CoarseSpace.solve before factor: call factor(x) first")
        weights = self._s.weights[:, None]
        rows, cols = self._s.rows, self._s.cols
        coarse_r = torch.zeros(self.num_patches, 3, dtype=torch.float64, device=r.device)
        coarse_r = coarse_r.index_add(0, cols, weights * r.double()[rows]).reshape(-1, 1)
        parts = [torch.cholesky_solve(coarse_r[c0:c1], chol)
                 for (c0, c1), chol in zip(self._s.coarse_ranges, self._factors)]
        coarse_z = torch.cat(parts).reshape(self.num_patches, 3)
        z = torch.zeros(r.shape[0], 3, dtype=torch.float64, device=r.device)
        return z.index_add(0, rows, weights * coarse_z[cols]).to(r.dtype)

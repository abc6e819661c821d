"""The coarse matrices Pᵀ K P of a garment topology from K's vertex-pair blocks, in one launch.

Pᵀ K P is linear in K's 3×3 pair blocks K_p: its block (I, J) is Σ_p G[(I, J), p] K_p, with G a
sparse operator fixed by the topology (`physics.coarse_space`). `GalerkinProduct` holds G in
CSR form and forms every coarse block of the garments of one topology with one Warp launch (a
thread per garment and coarse block, reading G's row and the garment's pair blocks), writing
each block's nine entries straight to where they go in the garments' coarse matrices (dense, or a
band's lower triangle: the blocks and entries a band does not store are neither formed nor
written). The same kernel runs on the CPU and on CUDA. Not differentiated: the coarse matrix is
the preconditioner's, a constant of each solver step.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch
from torch import Tensor

from physdrape.warp_runtime import defined_once, launch_arg, torch_stream, warp

__all__ = ["GalerkinProduct"]


@defined_once
def _kernels():
    """Define the kernel (first call only; Warp caches the compiled code on disk)."""
    wp = warp()

    @wp.kernel(enable_backward=False)
    def galerkin_kernel(indptr: wp.array(dtype=wp.int32), columns: wp.array(dtype=wp.int32),
                        weights: wp.array(dtype=wp.float64), pair_start: wp.array(dtype=wp.int32),
                        blocks: wp.array(dtype=wp.mat33d), destination: wp.array3d(dtype=wp.int32),
                        out: wp.array(dtype=wp.float64)):
        """out[destination[g, r, e]] = (Σ_k weights[k] · blocks[pair_start[g] + columns[k]])[e] over
        G's row r (k in indptr[r] … indptr[r + 1]), for the entries e = 3 a + b with a destination ≥ 0."""
        g, r = wp.tid()
        start = pair_start[g]
        total = wp.mat33d()
        for k in range(indptr[r], indptr[r + 1]):
            total += weights[k] * blocks[start + columns[k]]
        for a in range(3):
            for b in range(3):
                where = destination[g, r, 3 * a + b]
                if where >= 0:
                    out[where] = total[a, b]

    return {"wp": wp, "galerkin": galerkin_kernel}


class GalerkinProduct:
    """Pᵀ K P of the garments of one topology, formed from K's pair blocks into their coarse matrices.

    Args:
        operator: G, (coarse blocks, pairs) scipy CSR: coarse block r = Σ_p G[r, p] K_p.
        pair_start: (garments,) int: the row of each garment's first pair in the batch's pair
            blocks (a garment's pairs are consecutive rows, in G's column order).
        destination: (garments, coarse blocks · 9) int: where entry e = 3 a + b of coarse block r
            goes in the flat buffer of coarse matrices, column r · 9 + e; < 0: not stored (a
            band's upper triangle).
        device: where the launch runs.
    """

    def __init__(self, operator: sp.csr_matrix, pair_start: np.ndarray, destination: np.ndarray,
                 device: torch.device) -> None:
        garments = len(pair_start)
        if destination.shape != (garments, 9 * operator.shape[0]):
            raise ValueError(f"GalerkinProduct: G {operator.shape}, {garments} garments and destinations "
                             f"{destination.shape} disagree (need destinations (garments, 9 · G's rows))")
        destination = destination.reshape(garments, -1, 9)
        stored = (destination >= 0).any(axis=(0, 2))  # the coarse blocks some garment stores an entry of
        operator = operator[stored].tocsr()
        self.num_blocks = int(stored.sum())

        def on_device(array: np.ndarray, dtype) -> Tensor:
            return torch.from_numpy(np.ascontiguousarray(array, dtype=dtype)).to(device)

        self._indptr = on_device(operator.indptr, np.int32)
        self._columns = on_device(operator.indices, np.int32)
        self._weights = on_device(operator.data, np.float64)
        self._pair_start = on_device(pair_start, np.int32)
        self._destination = on_device(np.where(destination[:, stored] >= 0, destination[:, stored], -1), np.int32)

    def __call__(self, blocks: Tensor, out: Tensor) -> None:
        """Write the garments' coarse blocks from pair blocks (P, 3, 3) float64 into the flat
        float64 buffer `out` at their destinations (the other entries of `out` are left as they are)."""
        if blocks.dtype != torch.float64 or out.dtype != torch.float64 or out.dim() != 1:
            raise ValueError(f"GalerkinProduct needs float64 pair blocks and a flat float64 buffer, got "
                             f"{blocks.dtype} {tuple(blocks.shape)} and {out.dtype} {tuple(out.shape)}")
        garments = self._pair_start.shape[0]
        if not garments or not self.num_blocks:
            return
        kernels = _kernels()
        wp = kernels["wp"]
        with torch_stream(out.device):
            wp.launch(kernels["galerkin"], dim=(garments, self.num_blocks), device=wp.device_from_torch(out.device),
                      inputs=[launch_arg(self._indptr, wp.int32), launch_arg(self._columns, wp.int32),
                              launch_arg(self._weights, wp.float64), launch_arg(self._pair_start, wp.int32),
                              launch_arg(blocks.contiguous(), wp.mat33d), launch_arg(self._destination, wp.int32)],
                      outputs=[launch_arg(out, wp.float64)])

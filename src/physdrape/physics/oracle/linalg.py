"""The oracle's sparse linear algebra: assembly of element blocks into one symmetric matrix (and
of the vertex-pair terms into another, `_pair_hessian`), and its factorisation (CHOLMOD through
cvxopt, or SuperLU in symmetric mode)."""

from __future__ import annotations

import contextlib
import enum
import os
import sys

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from torch import Tensor

from physdrape.physics.cloth import Cloth
from physdrape.physics.layers import layer_pair_blocks
from physdrape.physics.stitches import stitch_pair_blocks


class LinearSolver(str, enum.Enum):
    """Sparse symmetric solver of the Newton system. AUTO: CHOLMOD (cvxopt) if installed, else
    SuperLU."""

    AUTO = "auto"
    CHOLMOD = "cholmod"
    SUPERLU = "superlu"


class _Assembler:
    """Scatters element blocks into the lower triangle of a fixed CSC pattern (3V × 3V).

    The pattern holds every face block (9×9), hinge block (12×12) and vertex diagonal block (3×3);
    `assemble` only sums values into it (np.bincount with a precomputed map).
    """

    def __init__(self, faces: np.ndarray, hinges: np.ndarray, num_verts: int) -> None:
        n = 3 * num_verts
        self.n = n
        rows, cols, self.sizes = [], [], []
        for elems in (faces, hinges, np.arange(num_verts)[:, None]):
            k = elems.shape[1]
            dof = (3 * elems[:, :, None] + np.arange(3)).reshape(len(elems), 3 * k)  # (E, 3k)
            rows.append(np.broadcast_to(dof[:, :, None], (len(elems), 3 * k, 3 * k)).reshape(-1))
            cols.append(np.broadcast_to(dof[:, None, :], (len(elems), 3 * k, 3 * k)).reshape(-1))
            self.sizes.append(len(elems) * 9 * k * k)
        rows, cols = np.concatenate(rows), np.concatenate(cols)
        self.lower = rows >= cols
        key = cols[self.lower].astype(np.int64) * n + rows[self.lower]  # column-major → CSC order
        uniq, self.inverse = np.unique(key, return_inverse=True)
        self.indices = (uniq % n).astype(np.int32)
        counts = np.bincount((uniq // n).astype(np.int64), minlength=n)
        self.indptr = np.concatenate([[0], np.cumsum(counts)]).astype(np.int32)
        self.nnz = uniq.shape[0]
        # position of each vertex's diagonal entries (for the regularisation)
        diag_key = np.arange(n, dtype=np.int64) * (n + 1)
        self.diag_pos = np.searchsorted(uniq, diag_key)

    def assemble(self, face_blocks: np.ndarray, hinge_blocks: np.ndarray, vert_blocks: np.ndarray) -> np.ndarray:
        """CSC data of the lower triangle, from blocks (F, 9, 9), (H, 12, 12), (V, 3, 3)."""
        values = np.concatenate([face_blocks.reshape(-1), hinge_blocks.reshape(-1), vert_blocks.reshape(-1)])
        return np.bincount(self.inverse, weights=values[self.lower], minlength=self.nnz)

    def lower_matrix(self, data: np.ndarray) -> sp.csc_matrix:
        return sp.csc_matrix((data, self.indices, self.indptr), shape=(self.n, self.n))


@contextlib.contextmanager
def silenced(fd: int):
    """Silence C-level writes to file descriptor `fd` (1 = stdout, 2 = stderr) inside the block."""
    (sys.stdout if fd == 1 else sys.stderr).flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), fd)
            yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)


def _diagonal_positions(lower: sp.csc_matrix) -> np.ndarray:
    """Index into lower.data of each diagonal entry of a sorted lower-triangular CSC matrix.

    The diagonal is the first stored entry of each column (rows ≥ column, sorted); every column
    must store it (the element patterns here always include the vertex diagonal blocks).
    """
    first = lower.indptr[:-1]
    if not np.array_equal(lower.indices[first], np.arange(lower.shape[0])):
        raise RuntimeError("internal: the Newton matrix is missing diagonal entries")
    return first


class _SparseSolver:
    """Solves A x = rhs for symmetric A given by its sorted lower-triangular CSC matrix; raises
    ValueError when A is not positive definite (CHOLMOD) or singular (SuperLU). CHOLMOD keeps the
    symbolic analysis of the last sparsity pattern and refactors numerically while it repeats."""

    def __init__(self, kind: LinearSolver) -> None:
        self.kind = kind
        self._pattern: tuple[np.ndarray, np.ndarray] | None = None
        self._rows = self._cols = self._symbolic = None

    def solve(self, lower: sp.csc_matrix, rhs: np.ndarray) -> np.ndarray:
        if self.kind is LinearSolver.SUPERLU:
            full = (lower + sp.tril(lower, k=-1).T).tocsc()
            lu = spla.splu(full, permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0, options={"SymmetricMode": True})
            out = lu.solve(rhs)
            if not np.all(np.isfinite(out)):
                raise ValueError("SuperLU returned a non-finite solution (singular system)")
            return out
        from cvxopt import cholmod, matrix, spmatrix  # optional dependency

        n = lower.shape[0]
        pattern = self._pattern
        if pattern is None or not (np.array_equal(pattern[0], lower.indptr) and np.array_equal(pattern[1], lower.indices)):
            cols = np.repeat(np.arange(n, dtype=np.int64), np.diff(lower.indptr))
            self._rows, self._cols = matrix(lower.indices.astype(np.int64)), matrix(cols)
            self._symbolic = None
            self._pattern = (lower.indptr.copy(), lower.indices.copy())
        a = spmatrix(matrix(np.ascontiguousarray(lower.data, dtype=np.float64)), self._rows, self._cols, (n, n))
        if self._symbolic is None:
            self._symbolic = cholmod.symbolic(a, uplo="L")
        try:
            cholmod.numeric(a, self._symbolic)
        except ArithmeticError as exc:
            raise ValueError(f"the Newton matrix is not positive definite (CHOLMOD: {exc})") from None
        x = matrix(np.ascontiguousarray(rhs, dtype=np.float64))
        cholmod.solve(self._symbolic, x)
        return np.asarray(x).reshape(-1)


def _solve_fixed(lower: sp.csc_matrix, diag_pos: np.ndarray, rhs: np.ndarray, fixed_verts: np.ndarray,
                 solver: _SparseSolver) -> np.ndarray:
    """Solve the Newton system with the dofs of `fixed_verts` (V,) bool held (their step is 0)."""
    n = lower.shape[0]
    fixed = np.repeat(fixed_verts, 3)
    cols = np.repeat(np.arange(n), np.diff(lower.indptr))
    data = lower.data.copy()
    data[fixed[lower.indices] | fixed[cols]] = 0.0
    data[diag_pos[fixed]] = 1.0
    reduced = sp.csc_matrix((data, lower.indices, lower.indptr), shape=lower.shape)
    return solver.solve(reduced, np.where(fixed, 0.0, rhs))


def _resolve_solver(solver: LinearSolver | str) -> LinearSolver:
    """AUTO → CHOLMOD when cvxopt is installed, else SuperLU; CHOLMOD without cvxopt is an error."""
    solver = LinearSolver(solver)
    if solver is LinearSolver.SUPERLU:
        return solver
    try:
        import cvxopt.cholmod  # noqa: F401  (optional dependency)
    except ImportError:
        if solver is LinearSolver.CHOLMOD:
            raise ImportError("solver='cholmod' needs the cvxopt package: pip install cvxopt "
                              "(or use solver='superlu')") from None
        return LinearSolver.SUPERLU
    return LinearSolver.CHOLMOD


def _pair_hessian(x: Tensor, cloth: Cloth, hess_c):
    """The Hessian terms that couple vertices outside faces and hinges, as one sparse (3V, 3V)
    matrix: the IPC barrier's `hess_c` and the exact (PSD) pair blocks [[H, −H], [−H, H]] of the
    stitches and the layer order; None without any."""
    out = hess_c
    for pairs, blocks in ((cloth.stitches, stitch_pair_blocks), (cloth.layers, layer_pair_blocks)):
        if pairs is None:
            continue
        h = blocks(x, pairs).numpy()  # (P, 3, 3)
        i, j = pairs.pairs[:, 0].numpy(), pairs.pairs[:, 1].numpy()
        axis = np.arange(3)
        rows, cols, vals = [], [], []
        for a, b, sign in ((i, i, 1.0), (j, j, 1.0), (i, j, -1.0), (j, i, -1.0)):
            rows.append((3 * a[:, None, None] + axis[None, :, None]).repeat(3, 2).reshape(-1))
            cols.append((3 * b[:, None, None] + axis[None, None, :]).repeat(3, 1).reshape(-1))
            vals.append(sign * h.reshape(-1))
        n = 3 * cloth.num_verts
        matrix = sp.coo_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                               shape=(n, n)).tocsc()
        out = matrix if out is None else out + matrix
    return out

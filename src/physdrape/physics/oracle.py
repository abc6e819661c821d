"""The physics oracle: per-instance projected-Newton minimisation of the garment's static energy.

Minimises E = E_strain + E_bend + E_grav + E_contact of every garment of a packed batch from a
start x0 (X_init, or any drape such as the model's output) to a stated tolerance. It gives

- the reference energies evaluation reports against (the best a drape can reach from that start),
- a refinement mode that polishes a drape,
- the classical-solver wall time PhysDrape's speed is compared with (DESIGN.md Sec. 5).

Method (projected Newton, float64 throughout):

1. Per-element Hessians (`physdrape.physics.hessians`): StVK strain in closed form; bending by its
   Gauss-Newton part k∇θ∇θᵀ (closed form, PSD; default) or by batched autograd. With
   ``projection="auto"`` (default) the exact assembled Hessian is factorised first and used when
   it is positive definite (quadratic convergence at the end, where per-element projection
   over-stiffens compressed, wrinkling regions and Newton crawls); otherwise every element block
   is projected to PSD (eigenvalues clamped at 0) — classic projected Newton
   (``projection="always"`` throughout). Measured on a 4.7k-vertex top (bench/bench_oracle.py,
   one thread, shared 2-core CPU): classic projected Newton (autograd bending, always projected)
   248 iterations / 116 s to the tolerance; Gauss-Newton bending, always projected 89 / 49 s;
   Gauss-Newton + auto (the defaults) 76 / 29–43 s, ending at 6e-4 instead of 1e-2. Re-measured
   in the seventh session, with the face-centroid contact and CHOLMOD: 210 / 39 s to 9.4e-3 (the
   generated 4.9k-vertex Anny T-shirt from its template: 40 / 7.9 s).
2. Contact:
   - ``penalty``: E_c = k_c Σ ReLU(ε − d_i)³ over the vertices and the face centroids, with d
     from `BodySurface` (closest point and normal held fixed for the Hessian: 6 k_c ReLU(ε − d)
     n nᵀ; a centroid's share is a 9×9 face block). A line-search trial that moves a vertex or a
     centroid from outside the body to inside is rejected, so no iterate gains inside samples.
     Vertices alone are not enough: measured on two test instances, 49–93 faces (1.1–1.5 % of
     the area) lay on curved parts of the body with their centroids up to 1.4 mm inside while
     no vertex was.
   - ``ipc``: the barrier of PyPI ``ipctk`` between the garment and the posed body (a static
     obstacle in one ``CollisionMesh``; garment–body pairs only unless ``self_contact``), its
     Hessian added to the system (exact in the first "auto" attempt, ipctk's PSD projection in
     the projected one), every step clipped by ``compute_collision_free_stepsize`` (CCD):
     intersection-free by construction. Needs an intersection-free start.
3. Assembly into one symmetric sparse matrix (3V × 3V, block-diagonal over the garments) with a
   precomputed scatter map; a small diagonal regularisation keeps it definite (rigid motions the
   contact does not pin).
4. Solve with CHOLMOD's sparse Cholesky (PyPI ``cvxopt``): the symbolic analysis once per
   sparsity pattern (fixed within a call in penalty mode), a numeric factorisation per
   iteration; or SuperLU in symmetric mode. Measured on a 3k-vertex top's Newton matrix (9165
   dofs, one thread): 21 ms per factorisation and solve, against 92 ms for cholespy's (which
   analyses the pattern every time) — and a factorisation that finds the matrix indefinite
   frees its memory, where cholespy leaked ~10 MB each (~40 MB per 10-iteration call here).
5. Backtracking Armijo line search on each garment's own total energy (the system is
   block-diagonal, so each garment takes its own step length); the step is first capped so that
   no vertex moves more than ``max_step``. When it finds no step, or only one backtracked more
   than ten times (the penalty's distance field has kinks where the closest body feature
   switches, e.g. in concave regions), a Newton step on the vertices out of contact, with the
   contact vertices held, is searched instead.

Stopping: converged when, for every garment, the residual force (max over vertices not in
contact of ‖F_int + F_contact‖ / (m_i g)) is below ``tol`` and the relative energy change of the
last iteration is below ``energy_tol``; otherwise at ``max_iters``, ``time_budget_s`` or when the
line search cannot decrease the energy any more.
"""

from __future__ import annotations

import contextlib
import enum
import math
import os
import sys
import time
from dataclasses import dataclass, field, fields, replace

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
import torch
from torch import Tensor

from physdrape.physics.bending import bend_energy, bend_forces
from physdrape.physics.cloth import Cloth
from physdrape.physics.collision import DEFAULT_MARGIN, DEFAULT_STIFFNESS
from physdrape.physics.gravity import gravity_energy, gravity_forces
from physdrape.physics.hessians import bend_gauss_newton_hessian, bend_hessian, strain_hessian
from physdrape.physics.strain import strain_energy, strain_forces

__all__ = [
    "BendHessian",
    "ContactMode",
    "IterationRecord",
    "LinearSolver",
    "OracleResult",
    "Projection",
    "relax",
]

#: Default IPC barrier stiffness κ and activation distance d̂ [m] (DESIGN.md Sec. 5).
DEFAULT_BARRIER_STIFFNESS = 1e5
DEFAULT_DHAT = 3e-3


class ContactMode(str, enum.Enum):
    """How the body holds the garment up: cubic penalty on signed distances, or the IPC barrier."""

    PENALTY = "penalty"
    IPC = "ipc"


class LinearSolver(str, enum.Enum):
    """Sparse symmetric solver of the Newton system. AUTO: CHOLMOD (cvxopt) if installed, else
    SuperLU."""

    AUTO = "auto"
    CHOLMOD = "cholmod"
    SUPERLU = "superlu"


class Projection(str, enum.Enum):
    """When to project element Hessians to PSD. AUTO: try the exact Hessian first and project only
    when the assembled matrix is not positive definite (needs CHOLMOD, which reports it);
    ALWAYS: classic projected Newton."""

    AUTO = "auto"
    ALWAYS = "always"


class BendHessian(str, enum.Enum):
    """Bending Hessian: full autograd Hessian projected to PSD, or its Gauss-Newton part k∇θ∇θᵀ."""

    PROJECTED = "projected"
    GAUSS_NEWTON = "gauss_newton"


@dataclass(frozen=True)
class IterationRecord:
    """One Newton iteration (iteration 0 = the start state; its times are zero).

    energy: total energy summed over garments [J]; energy_change: max over garments of
    |ΔE_g| / |E_g| for this iteration; residual: max over garments and over vertices not in
    contact of ‖F‖ / (m_i g); residual_all: the same over all vertices; step: min over garments of
    the accepted step length; num_contact: vertices in contact (themselves or through a face's
    centroid); num_inside: vertices and face centroids inside the body (BodySurface's inside
    test); regularization: the diagonal shift used, relative to the
    mean diagonal of the Hessian; projected: whether the element Hessians were projected to PSD
    (False: the exact Hessian was positive definite); t_hessian, t_assembly, t_solve, t_line_search: seconds spent
    in each phase; wall: seconds since the start of `relax`.
    """

    iteration: int
    energy: float
    energy_change: float
    residual: float
    residual_all: float
    step: float
    num_contact: int
    num_inside: int
    regularization: float = 0.0
    projected: bool = True
    t_hessian: float = 0.0
    t_assembly: float = 0.0
    t_solve: float = 0.0
    t_line_search: float = 0.0
    wall: float = 0.0


@dataclass(frozen=True)
class OracleResult:
    """Result of `relax`.

    x: relaxed positions [m], shape (ΣV, 3), dtype of x0.
    energy_terms: per-garment totals [J] at x, {"strain", "bend", "gravity", "contact", "total"}: (G,)
        float64; "contact" is the penalty or the IPC barrier energy, as selected.
    history: one `IterationRecord` per iteration, the start state first.
    converged: every garment met both tolerances (or met the residual one and the line search
        found no further decrease: the floating-point floor of the energy).
    reason: why it stopped ("converged", "max_iters", "time_budget", "line_search").
    residual: per-garment residual force at x (max over free vertices of ‖F‖/(m_i g)), (G,).
    wall_time: seconds of the whole call; timings: seconds per phase summed over the iterations
        ("hessian", "assembly", "solve", "line_search").
    """

    x: Tensor
    energy_terms: dict[str, Tensor]
    history: list[IterationRecord]
    converged: bool
    reason: str
    residual: Tensor
    wall_time: float = 0.0
    timings: dict[str, float] = field(default_factory=dict)


# ------------------------------------------------------------------------------------------
# Sparse assembly
# ------------------------------------------------------------------------------------------


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
        from cvxopt import cholmod, matrix, spmatrix

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


def _resolve_solver(solver: LinearSolver | str) -> LinearSolver:
    solver = LinearSolver(solver)
    if solver is LinearSolver.SUPERLU:
        return solver
    try:
        import cvxopt.cholmod  # noqa: F401
    except ImportError:
        if solver is LinearSolver.CHOLMOD:
            raise ImportError("solver='cholmod' needs the cvxopt package: pip install cvxopt "
                              "(or use solver='superlu')") from None
        return LinearSolver.SUPERLU
    return LinearSolver.CHOLMOD


# ------------------------------------------------------------------------------------------
# Contact models
# ------------------------------------------------------------------------------------------


class _PenaltyContact:
    """k_c Σ ReLU(ε − d)³ at the vertices and the face centroids, against the bodies of a
    `BodySurface` (closest point held fixed).

    Sampling the centroids too keeps the faces themselves out of the body: with vertices alone a
    face lying on a convex part of the body (a shoulder, an arm) dips its middle up to ~1.5 mm
    inside while its corners sit in the margin, which is what B2G (by face centroid) counts.
    A centroid's force is shared equally by its face's three corners.
    """

    def __init__(self, bodies, vert_body: Tensor, faces: Tensor, *, stiffness: float, margin: float) -> None:
        self.bodies, self.vert_body, self.faces = bodies, vert_body, faces
        self.face_body = vert_body[faces[:, 0]]
        self.stiffness, self.margin = stiffness, margin

    def _query(self, x: Tensor):
        """Queries of the vertices and of the centroids: (vertex query, centroid query)."""
        x_q = x.to(self.bodies.verts.dtype)
        return (self.bodies.query(x_q, body_index=self.vert_body),
                self.bodies.query(x_q[self.faces].mean(1), body_index=self.face_body))

    def _depth(self, q, dtype) -> Tensor:
        return (self.margin - q.signed_distance.to(dtype)).clamp_min(0.0)

    def state(self, x: Tensor) -> dict:
        """Per-sample energies, the gradient on the vertices (V, 3), contact and inside flags."""
        qv, qc = self._query(x)
        dv, dc = self._depth(qv, x.dtype), self._depth(qc, x.dtype)
        nv, nc = qv.normal.to(x.dtype), qc.normal.to(x.dtype)
        grad = -(3.0 * self.stiffness * dv**2)[:, None] * nv
        corner = -(self.stiffness * dc**2)[:, None] * nc  # 3 k d² n / 3 per corner
        grad = grad.index_add(0, self.faces.reshape(-1), corner.repeat_interleave(3, dim=0))
        contact = dv > 0  # a vertex is in contact through itself or through a face of its own
        contact[self.faces[dc > 0].reshape(-1)] = True
        return {
            "vertex_energy": self.stiffness * dv**3, "face_energy": self.stiffness * dc**3, "grad": grad,
            "normal": nv, "depth": dv, "face_normal": nc, "face_depth": dc,
            "inside": torch.cat([qv.inside, qc.inside]), "contact": contact,
        }

    def hessians(self, st: dict) -> tuple[Tensor, Tensor]:
        """Gauss–Newton blocks of the contact energy: vertices (V, 3, 3), faces (F, 9, 9)."""
        n = st["normal"]
        hv = (6.0 * self.stiffness * st["depth"])[:, None, None] * n[:, :, None] * n[:, None, :]
        nc = st["face_normal"]
        hc = (6.0 * self.stiffness * st["face_depth"] / 9.0)[:, None, None] * nc[:, :, None] * nc[:, None, :]
        hf = hc[:, None, :, None, :].expand(-1, 3, -1, 3, -1).reshape(-1, 9, 9)
        return hv, hf

    def trial(self, x: Tensor) -> tuple[Tensor, Tensor, Tensor]:
        """(vertex energies (V,), face energies (F,), inside flags of vertices then centroids (V + F,))."""
        qv, qc = self._query(x)
        k = self.stiffness
        return k * self._depth(qv, x.dtype)**3, k * self._depth(qc, x.dtype)**3, torch.cat([qv.inside, qc.inside])


def penalty_contact_energy(x: Tensor, cloth: Cloth, bodies, vert_body: Tensor, *,
                           stiffness: float = DEFAULT_STIFFNESS, margin: float = DEFAULT_MARGIN) -> Tensor:
    """The penalty contact energy `relax` minimises, per garment [J] (G,): k_c Σ ReLU(ε − d)³ over
    the vertices and the face centroids. x (ΣV, 3) [m]; vert_body: body of each vertex (ΣV,)."""
    e_v, e_f, _ = _PenaltyContact(bodies, vert_body, cloth.faces, stiffness=stiffness, margin=margin).trial(x)
    return cloth.sum_per_garment(e_v, cloth.vert_garment) + cloth.sum_per_garment(e_f, cloth.face_garment)


def _import_ipctk():
    try:
        import ipctk
    except ImportError:
        raise ImportError("contact='ipc' needs the ipctk package (IPC Toolkit): pip install ipctk; "
                          "or use contact='penalty'") from None
    return ipctk


class _IPCContact:
    """IPC barrier between each garment and its posed body (static obstacle), one mesh per garment."""

    def __init__(self, x: Tensor, cloth: Cloth, bodies, body_index: Tensor, vert_offsets: list[int], *,
                 stiffness: float, dhat: float, self_contact: bool) -> None:
        ipctk = _import_ipctk()
        self.ipctk, self.stiffness, self.dhat = ipctk, stiffness, dhat
        self.bodies = bodies
        self.offsets = vert_offsets
        body_verts = bodies.verts.detach().to(torch.float64).cpu().numpy()
        body_faces = bodies.faces.cpu().numpy().astype(np.int32)
        faces = cloth.faces.cpu().numpy()
        self.meshes, self.body_pos = [], []
        for g in range(len(vert_offsets) - 1):
            lo, hi = vert_offsets[g], vert_offsets[g + 1]
            gf = faces[(faces >= lo).all(1) & (faces < hi).all(1)] - lo
            bv = body_verts[int(body_index[g])]
            nv = hi - lo
            all_faces = np.concatenate([gf, body_faces + nv]).astype(np.int32)
            rest = np.asfortranarray(np.concatenate([x[lo:hi].detach().cpu().numpy(), bv]))
            mesh = ipctk.CollisionMesh(rest, np.asfortranarray(ipctk.edges(all_faces)), np.asfortranarray(all_faces))
            if self_contact:
                mesh.can_collide = ipctk.make_static_obstacle_filter(nv)
            else:  # only garment–body pairs: one component for the garment, one for the body
                link_g = np.stack([np.zeros(nv - 1), np.arange(1, nv), np.arange(1, nv)], 1)
                link_b = np.stack([np.full(len(bv) - 1, nv), np.arange(nv + 1, nv + len(bv)),
                                   np.arange(nv + 1, nv + len(bv))], 1)
                comp = np.asfortranarray(np.concatenate([all_faces, link_g, link_b]).astype(np.int32))
                mesh.can_collide = ipctk.make_connected_components_filter(comp)
            self.meshes.append(mesh)
            self.body_pos.append(bv)
        self.potential = ipctk.BarrierPotential(dhat, stiffness)

    def _full(self, x_np: np.ndarray, g: int) -> np.ndarray:
        lo, hi = self.offsets[g], self.offsets[g + 1]
        return np.asfortranarray(np.concatenate([x_np[lo:hi], self.body_pos[g]]))

    def _collisions(self, full: np.ndarray, g: int):
        col = self.ipctk.NormalCollisions()
        col.build(self.meshes[g], full, self.dhat)
        return col

    def check_start(self, x_np: np.ndarray) -> None:
        for g, mesh in enumerate(self.meshes):
            if self.ipctk.has_intersections(mesh, self._full(x_np, g)):
                raise ValueError(f"garment {g} intersects its body (or itself) at the start state; IPC needs an "
                                 "intersection-free start: relax it with contact='penalty' first, or push it out "
                                 "with the collision handler")

    def energy(self, x_np: np.ndarray) -> np.ndarray:
        """Barrier energy per garment (G,) [J]."""
        out = np.zeros(len(self.meshes))
        for g, mesh in enumerate(self.meshes):
            full = self._full(x_np, g)
            out[g] = self.potential(self._collisions(full, g), mesh, full)
        return out

    def grad_hess(self, x_np: np.ndarray, *, project: bool = True) -> tuple[np.ndarray, sp.csc_matrix]:
        """Gradient (V, 3) and Hessian (3V × 3V) of the barrier; project=True: ipctk's per-collision
        PSD projection (eigenvalues clamped), else the exact Hessian."""
        num_verts = self.offsets[-1]
        grad = np.zeros((num_verts, 3))
        blocks = []
        method = self.ipctk.PSDProjectionMethod.CLAMP if project else self.ipctk.PSDProjectionMethod.NONE
        for g, mesh in enumerate(self.meshes):
            lo, hi = self.offsets[g], self.offsets[g + 1]
            full = self._full(x_np, g)
            col = self._collisions(full, g)
            gr = self.potential.gradient(col, mesh, full).reshape(-1, 3)
            grad[lo:hi] = gr[: hi - lo]
            hess = self.potential.hessian(col, mesh, full, method)
            n3 = 3 * (hi - lo)
            blocks.append(hess.tocsc()[:n3, :n3])
        return grad, sp.block_diag(blocks, format="csc")

    def max_step(self, x_np: np.ndarray, p_np: np.ndarray) -> np.ndarray:
        """Largest collision-free step length per garment along p (CCD), (G,)."""
        out = np.ones(len(self.meshes))
        for g, mesh in enumerate(self.meshes):
            _lo, _hi = self.offsets[g], self.offsets[g + 1]
            out[g] = self.ipctk.compute_collision_free_stepsize(mesh, self._full(x_np, g),
                                                                self._full(x_np + p_np, g))
        return out


# ------------------------------------------------------------------------------------------
# The solver
# ------------------------------------------------------------------------------------------


def _element_energies(x: Tensor, cloth: Cloth) -> dict[str, Tensor]:
    return {
        "strain": cloth.sum_per_garment(strain_energy(x, cloth), cloth.face_garment),
        "bend": cloth.sum_per_garment(bend_energy(x, cloth), cloth.hinge_garment),
        "gravity": cloth.sum_per_garment(gravity_energy(x, cloth), cloth.vert_garment),
    }


def relax(
    x0: Tensor,
    cloth: Cloth,
    bodies,
    body_index: Tensor | None = None,
    *,
    contact: ContactMode | str = ContactMode.PENALTY,
    tol: float = 1e-2,
    energy_tol: float = 1e-6,
    max_iters: int = 200,
    time_budget_s: float | None = None,
    contact_stiffness: float = DEFAULT_STIFFNESS,
    margin: float = DEFAULT_MARGIN,
    barrier_stiffness: float = DEFAULT_BARRIER_STIFFNESS,
    dhat: float = DEFAULT_DHAT,
    self_contact: bool = False,
    max_step: float = 0.02,
    regularization: float = 1e-8,
    bend: BendHessian | str = BendHessian.GAUSS_NEWTON,
    projection: Projection | str = Projection.AUTO,
    solver: LinearSolver | str = LinearSolver.AUTO,
    max_line_search: int = 40,
    callback=None,
) -> OracleResult:
    """Minimise each garment's E_strain + E_bend + E_grav + E_contact by projected Newton.

    Args:
        x0: start positions [m], shape (ΣV, 3) packed like `cloth` (any float dtype; solved in float64).
        cloth: `Cloth.build(...)` of the garment batch.
        bodies: `physdrape.geometry.proximity.BodySurface` holding the posed bodies.
        body_index: body of each garment, (G,) int; default 0 for all.
        contact: "penalty" (k_c ReLU(ε − d)³, `contact_stiffness` [J/m³], `margin` ε [m]) or "ipc"
            (ipctk barrier, `barrier_stiffness` κ, `dhat` d̂ [m], CCD-clipped steps; needs
            ``pip install ipctk``; `self_contact` adds garment–garment barrier pairs).
        tol: residual tolerance: max over vertices not in contact of ‖F_int + F_contact‖ / (m_i g).
        energy_tol: relative energy change tolerance |ΔE_g| / |E_g| over the last iteration (both must
            hold; E_g includes gravity, so it depends on the height of the origin — y = 0 at the
            body's feet or centre keeps it meaningful).
        max_iters, time_budget_s: iteration and wall-time [s] budgets.
        max_step: largest vertex displacement of one Newton step [m].
        regularization: diagonal term added to the Hessian, relative to its mean diagonal
            (raised ×100 until the factorisation succeeds).
        bend: "gauss_newton" (k∇θ∇θᵀ, analytic, PSD; default: measured ~4× faster to the tolerance)
            or "projected" (the full Hessian by batched autograd, eigenvalues clamped).
        projection: "auto" (exact Hessian when positive definite, else projected; with cholmod)
            or "always" (projected Newton throughout).
        solver: "auto", "cholmod" (cvxopt's CHOLMOD) or "superlu" (`splu`, MMD_AT_PLUS_A,
            symmetric mode).
        callback: called as callback(record, x) after every iteration.

    Returns:
        `OracleResult`; `history[k]` records iteration k (energy, residual, per-phase times).
    """
    t_start = time.perf_counter()
    contact = ContactMode(contact)
    bend = BendHessian(bend)
    solver = _resolve_solver(solver)
    try_exact = Projection(projection) is Projection.AUTO and solver is LinearSolver.CHOLMOD
    linear = _SparseSolver(solver)
    if x0.ndim != 2 or x0.shape != (cloth.num_verts, 3):
        raise ValueError(f"x0 must be packed positions of shape ({cloth.num_verts}, 3) like the cloth, "
                         f"got {tuple(x0.shape)}")
    if not torch.isfinite(x0).all():
        raise ValueError("x0 contains NaN/inf")
    G = cloth.num_garments
    body_index = torch.zeros(G, dtype=torch.int64) if body_index is None else torch.as_tensor(body_index).long()
    if body_index.shape != (G,):
        raise ValueError(f"body_index must have one entry per garment ({G},), got {tuple(body_index.shape)}")
    if int(body_index.min()) < 0 or int(body_index.max()) >= bodies.batch_size:
        raise ValueError(f"indices in body_index must be in [0, {bodies.batch_size}) (got {body_index.tolist()})")

    in_dtype = x0.dtype
    dt = torch.float64
    cloth64 = _cloth_to(cloth, dt)
    x = x0.detach().to(dt).clone()
    vg = cloth64.vert_garment
    vert_body = body_index[vg]
    weight = cloth64.mass * cloth64.gravity[vg].norm(dim=-1)  # m_i g [N]
    counts = torch.bincount(vg, minlength=G)
    offsets = [0] + torch.cumsum(counts, 0).tolist()

    asm = _Assembler(cloth64.faces.numpy(), cloth64.hinges.numpy(), cloth64.num_verts)
    sample_garment = torch.cat([vg, cloth64.face_garment])  # owner of each contact sample (vertices, centroids)
    if contact is ContactMode.PENALTY:
        pen = _PenaltyContact(bodies, vert_body, cloth64.faces, stiffness=contact_stiffness, margin=margin)
        ipc = None
    else:
        pen = _PenaltyContact(bodies, vert_body, cloth64.faces, stiffness=0.0, margin=dhat)  # contact flags / inside
        ipc = _IPCContact(x, cloth64, bodies, body_index, offsets, stiffness=barrier_stiffness, dhat=dhat,
                          self_contact=self_contact)
        ipc.check_start(x.numpy())

    def total_energy(xt: Tensor, contact_energy: Tensor) -> tuple[Tensor, dict]:
        terms = _element_energies(xt, cloth64)
        terms["contact"] = contact_energy
        return terms["strain"] + terms["bend"] + terms["gravity"] + contact_energy, terms

    def contact_energy_at(xt: Tensor) -> tuple[Tensor, Tensor]:
        """Per-garment contact energy (G,) and per-vertex inside flags at a trial state."""
        e_v, e_f, inside = pen.trial(xt)
        if ipc is None:
            return cloth64.sum_per_garment(e_v, vg) + cloth64.sum_per_garment(e_f, cloth64.face_garment), inside
        return torch.from_numpy(ipc.energy(xt.numpy())), inside

    def gradient_state(xt: Tensor):
        st = pen.state(xt)
        f = strain_forces(xt, cloth64) + bend_forces(xt, cloth64) + gravity_forces(xt, cloth64)
        if ipc is None:
            grad_c = st["grad"]
            e_c = cloth64.sum_per_garment(st["vertex_energy"], vg) + cloth64.sum_per_garment(st["face_energy"],
                                                                                          cloth64.face_garment)
            hess_c = None
        else:
            grad_np, hess_c = ipc.grad_hess(xt.numpy(), project=not try_exact)
            grad_c = torch.from_numpy(grad_np)
            e_c = torch.from_numpy(ipc.energy(xt.numpy()))
        grad = -f + grad_c
        res_v = grad.norm(dim=-1) / weight
        free = ~st["contact"]
        res_free = torch.where(free, res_v, torch.zeros_like(res_v))
        res_g = torch.zeros(G, dtype=dt).scatter_reduce_(0, vg, res_free, reduce="amax")
        res_all_g = torch.zeros(G, dtype=dt).scatter_reduce_(0, vg, res_v, reduce="amax")
        return st, grad, e_c, hess_c, res_g, res_all_g

    def line_search(x: Tensor, p: Tensor, grad: Tensor, energy: Tensor, inside0: Tensor, skip: Tensor):
        """Backtracking Armijo per garment along p; garments in `skip` stay put.

        A trial that moves a vertex or a face centroid from outside the body to inside is rejected. Returns the new
        positions, the step lengths (G,) and which garments accepted a step (G,) (skip counts as
        accepted).
        """
        slope = cloth64.sum_per_garment((grad * p).sum(-1), vg)  # (G,) < 0 for a descent direction
        descent = slope < 0
        if not bool(descent.all()):  # numerical trouble: steepest descent there
            p = torch.where(descent[vg][:, None], p, -grad / grad.norm(dim=-1).max().clamp_min(1e-300) * max_step)
            slope = cloth64.sum_per_garment((grad * p).sum(-1), vg)
        pmax = torch.zeros(G, dtype=dt).scatter_reduce_(0, vg, p.norm(dim=-1), reduce="amax")
        alpha = torch.clamp(max_step / pmax.clamp_min(1e-300), max=1.0)
        if ipc is not None:
            ccd = torch.from_numpy(ipc.max_step(x.numpy(), (alpha[vg][:, None] * p).numpy()))
            alpha = alpha * torch.where(ccd >= 1.0, torch.ones_like(ccd), 0.9 * ccd)  # stay short of contact
        alpha0 = alpha.clone()
        accepted = skip.clone()
        x_new = x.clone()
        for _ in range(max_line_search):
            trial = x + alpha[vg][:, None] * p
            e_c_t, inside_t = contact_energy_at(trial)
            e_t, _ = total_energy(trial, e_c_t)
            new_inside = (inside_t & ~inside0).to(torch.int64)
            bad = torch.zeros(G, dtype=torch.int64).index_add_(0, sample_garment, new_inside) > 0
            ok = (e_t <= energy + 1e-4 * alpha * slope) & ~bad & ~accepted
            if bool(ok.any()):
                take = ok[vg]
                x_new[take] = trial[take]
                accepted |= ok
            if bool(accepted.all()):
                break
            alpha = torch.where(accepted, alpha, 0.5 * alpha)
        return x_new, alpha, accepted, alpha / alpha0

    st, grad, e_c, hess_c, res_g, res_all_g = gradient_state(x)
    energy, terms = total_energy(x, e_c)
    history = [IterationRecord(0, float(energy.sum()), math.nan, float(res_g.max()), float(res_all_g.max()), 0.0,
                               int(st["contact"].sum()), int(st["inside"].sum()), wall=time.perf_counter() - t_start)]
    if callback is not None:
        callback(history[-1], x)
    timings = {"hessian": 0.0, "assembly": 0.0, "solve": 0.0, "line_search": 0.0}
    reason, converged = "max_iters", False
    change_g = torch.full((G,), math.inf, dtype=dt)
    reg = regularization
    exact_wait, exact_backoff = 0, 1  # iterations to skip the exact-Hessian attempt; next skip length
    for it in range(1, max_iters + 1):
        if bool((res_g < tol).all()) and bool((change_g < energy_tol).all()):
            reason, converged = "converged", True
            break
        if time_budget_s is not None and time.perf_counter() - t_start > time_budget_s:
            reason = "time_budget"
            break
        # -- Hessian blocks, assembly, factorisation + solve. With projection "auto", the exact
        # Hessian is tried first (quadratic convergence near a minimum, where per-element
        # projection over-stiffens compressed/buckled regions); when it is not positive definite
        # the factorisation says so and the per-element PSD projection is used. After a failed
        # exact attempt the next 1, 2, 4, … iterations skip it (reset on success): every failed
        # factorisation costs a factorisation's time.
        t_h = t_a = t_s = 0.0
        rhs = -grad.numpy().reshape(-1)
        p = None
        projected = True
        attempts = [False, True] if try_exact and exact_wait == 0 else [True]
        exact_wait = max(exact_wait - 1, 0)
        for project in attempts:
            t0 = time.perf_counter()
            hs = strain_hessian(x, cloth64, project=project)
            if bend is BendHessian.PROJECTED:
                hb = bend_hessian(x, cloth64, project=project)
            else:
                hb = bend_gauss_newton_hessian(x, cloth64)
            if ipc is None:
                hv, hf = pen.hessians(st)
                hs = hs + hf
            else:
                hv = torch.zeros(cloth64.num_verts, 3, 3, dtype=dt)
            t1 = time.perf_counter()
            data = asm.assemble(hs.numpy(), hb.numpy(), hv.numpy())
            diag_mean = float(np.mean(data[asm.diag_pos]))
            if hess_c is not None:
                if project and try_exact:  # the exact barrier Hessian was not PD: ipctk's projected one
                    hess_c = ipc.grad_hess(x.numpy(), project=True)[1]
                lower = (asm.lower_matrix(data) + sp.tril(hess_c)).tocsc()
                lower.sort_indices()
                diag_pos = _diagonal_positions(lower)
            else:
                lower = asm.lower_matrix(data)  # sorted CSC, diagonal in the pattern
                diag_pos = asm.diag_pos
            base_diag = lower.data[diag_pos].copy()
            t2 = time.perf_counter()
            t_h, t_a = t_h + t1 - t0, t_a + t2 - t1
            if not project:  # exact Hessian: one try at the current regularisation
                lower.data[diag_pos] = base_diag + reg * diag_mean
                try:
                    with silenced(2):  # CHOLMOD may print a warning when it finds the matrix indefinite
                        p = linear.solve(lower, rhs)
                    reg_used, projected = reg, False
                    t_s += time.perf_counter() - t2
                    exact_backoff = 1
                    break
                except (ValueError, RuntimeError):
                    t_s += time.perf_counter() - t2
                    exact_wait, exact_backoff = exact_backoff, 2 * exact_backoff
                    continue
            # projected: raise the regularisation until the factorisation succeeds
            while True:
                lower.data[diag_pos] = base_diag + reg * diag_mean
                try:
                    p = linear.solve(lower, rhs)
                    reg_used = reg
                    break
                except (ValueError, RuntimeError):
                    reg *= 100.0
                    if reg > 1e2:
                        raise RuntimeError("the Newton system stays singular even with a large regularisation; "
                                           "is every garment vertex in a face?") from None
            t_s += time.perf_counter() - t2
        t3 = time.perf_counter()
        t0, t1, t2 = t3 - (t_h + t_a + t_s), t3 - (t_a + t_s), t3 - t_s
        p = torch.from_numpy(p).reshape(-1, 3)
        # -- line search, one step length per garment
        done = (res_g < tol) & (change_g < energy_tol)  # converged garments stay put
        x_new, alpha, accepted, shrink = line_search(x, p, grad, energy, st["inside"], done)
        failed = (~accepted | (shrink < 1e-3)) & ~done  # no step, or one backtracked > 10 times
        if bool(failed.any()):
            # The Newton direction gave no (or a tiny) decrease (the penalty's distance field is not smooth
            # where closest features switch, e.g. in concave body regions): take a Newton step on
            # the vertices out of contact only, contact vertices held, and search again.
            fixed = st["contact"] | ~failed[vg]
            if not bool(fixed.all()):
                p_free = torch.from_numpy(_solve_fixed(lower, diag_pos, rhs, fixed.numpy(), linear)).reshape(-1, 3)
                x_free, alpha_free, acc_free, _ = line_search(x, p_free, grad, energy, st["inside"], ~failed)
                take = (acc_free & failed)
                x_new[take[vg]] = x_free[take[vg]]
                alpha = torch.where(take, alpha_free, alpha)
                accepted |= take
        alpha = torch.where(accepted & ~done, alpha, torch.zeros_like(alpha))
        progressed = bool((accepted & ~done).any())
        t4 = time.perf_counter()
        timings["hessian"] += t1 - t0
        timings["assembly"] += t2 - t1
        timings["solve"] += t3 - t2
        timings["line_search"] += t4 - t3
        x = x_new
        st, grad, e_c, hess_c, res_g, res_all_g = gradient_state(x)
        energy_old = energy
        energy, terms = total_energy(x, e_c)
        change_g = (energy_old - energy).abs() / energy.abs().clamp_min(1e-300)
        reg = max(regularization, reg / 10.0)
        history.append(IterationRecord(it, float(energy.sum()), float(change_g.max()), float(res_g.max()),
                                       float(res_all_g.max()), float(alpha.min()), int(st["contact"].sum()),
                                       int(st["inside"].sum()), reg_used, projected, t1 - t0, t2 - t1, t3 - t2, t4 - t3,
                                       time.perf_counter() - t_start))
        if callback is not None:
            callback(history[-1], x)
        if not progressed:
            reason = "line_search"
            break
    else:
        if bool((res_g < tol).all()) and bool((change_g < energy_tol).all()):
            reason, converged = "converged", True
    if reason == "line_search" and bool((res_g < tol).all()):
        converged = True  # at the floating-point floor of the energy with the residual met
    terms = {k: v.detach() for k, v in terms.items()}
    terms["total"] = energy.detach()
    return OracleResult(x=x.to(in_dtype), energy_terms=terms, history=history, converged=converged, reason=reason,
                        residual=res_g, wall_time=time.perf_counter() - t_start, timings=timings)


def _cloth_to(cloth: Cloth, dtype: torch.dtype) -> Cloth:
    """The same cloth with floating tensors in `dtype`."""
    if cloth.dtype == dtype:
        return cloth
    changes = {}
    for f in fields(cloth):
        value = getattr(cloth, f.name)
        if isinstance(value, Tensor) and value.is_floating_point():
            changes[f.name] = value.to(dtype)
    return replace(cloth, **changes)

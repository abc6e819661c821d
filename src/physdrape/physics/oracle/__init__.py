"""The physics oracle: per-instance projected-Newton minimisation of the garment's static energy.

`relax` minimises E = E_strain + E_bend + E_grav + E_contact of every garment of a packed batch
from a start x0 (X_init, or any drape such as the model's output) to a stated tolerance. It gives

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
   (``projection="always"`` throughout).
2. Contact:
   - ``penalty``: the term of `physdrape.physics.contact`, E_c = k_c Σ ReLU(ε − d)³ over the
     vertices and the face centroids, with d from `BodySurface` (closest point and normal held
     fixed for the Hessian: 6 k_c ReLU(ε − d) n nᵀ; a centroid's share is a 9×9 face block).
     A line-search trial that moves a vertex or a centroid from outside the body to inside is
     rejected, so no iterate gains inside samples. The centroids matter: a face lying on a curved
     part of the body can have its middle inside while none of its corners is.
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
   iteration, and an indefinite matrix reported as such (which drives the "auto" projection);
   or SuperLU in symmetric mode.
5. Backtracking Armijo line search on each garment's own total energy (the system is
   block-diagonal, so each garment takes its own step length); the step is first capped so that
   no vertex moves more than ``max_step``. When it finds no step, or only one backtracked more
   than ten times (the penalty's distance field has kinks where the closest body feature
   switches, e.g. in concave regions), a Newton step on the vertices out of contact, with the
   contact vertices held, is searched instead.
6. Pieces (`crossings`): a trial that makes a face of one piece of a multi-piece garment
   intersect a face of another piece where they did not is rejected too (the energy has no
   contact between pieces, and does not see a piece that is already through another), and the
   step searched instead also holds the corners of those faces.

Stopping: converged when, for every garment, the residual force (max over vertices not in
contact of ‖F_int + F_contact‖ / (m_i g)) is below ``tol`` and the relative energy change of the
last iteration is below ``energy_tol``; otherwise at ``max_iters``, ``time_budget_s`` or when the
line search cannot decrease the energy any more.

Modules: `newton` (the loop and `relax`), `linalg` (assembly and sparse solves), `ipc` (the
ipctk barrier), `crossings` (the guard of the pieces), `results` (what `relax` returns).
"""

from physdrape.physics.oracle.ipc import DEFAULT_BARRIER_STIFFNESS, DEFAULT_DHAT
from physdrape.physics.oracle.linalg import LinearSolver, silenced
from physdrape.physics.oracle.newton import BendHessian, ContactMode, Projection, relax
from physdrape.physics.oracle.results import IterationRecord, OracleResult

__all__ = [
    "DEFAULT_BARRIER_STIFFNESS",
    "DEFAULT_DHAT",
    "BendHessian",
    "ContactMode",
    "IterationRecord",
    "LinearSolver",
    "OracleResult",
    "Projection",
    "relax",
    "silenced",
]

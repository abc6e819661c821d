"""The oracle's Newton loop: `relax` checks its inputs and runs `_Newton`, which holds one call's
state (the float64 cloth, the contact model, the sparse system) and takes the steps."""

from __future__ import annotations

import enum
import math
import time
from dataclasses import dataclass, fields, replace

import numpy as np
import scipy.sparse as sp
import torch
from torch import Tensor

from physdrape.physics.cloth import Cloth
from physdrape.physics.contact import (
    DEFAULT_MARGIN,
    DEFAULT_STIFFNESS,
    contact_energy,
    contact_hessian_blocks,
    contact_vertices,
    garment_energy,
    plane_contact_forces,
    query_samples,
    sample_index,
)
from physdrape.physics.forces import energy_terms, internal_forces
from physdrape.physics.grip import grip_blocks
from physdrape.physics.hessians import bend_gauss_newton_hessian, bend_hessian, strain_hessian
from physdrape.physics.layers import followed
from physdrape.physics.oracle.crossings import PieceGuard
from physdrape.physics.oracle.ipc import DEFAULT_BARRIER_STIFFNESS, DEFAULT_DHAT, _IPCContact
from physdrape.physics.oracle.linalg import (
    LinearSolver,
    _Assembler,
    _diagonal_positions,
    _pair_hessian,
    _resolve_solver,
    _solve_fixed,
    _SparseSolver,
    silenced,
)
from physdrape.physics.oracle.results import IterationRecord, OracleResult

#: How far [m] a vertex moves before a multi-piece garment's layer pairs are searched again at the
#: current positions (`physics.layers.follow_pairs`): a pair holds its vertex on its side from the
#: search on, and a vertex reaching another piece between two searches comes from within this move
#: plus one step (`max_step`), inside the pairs' 4 cm reach. Far from rest that is a search at
#: nearly every iteration; near rest none, so the oracle can meet its tolerances (pairs found again
#: change the problem a little each time: searching every 5 iterations kept the polish of
#: male_casualsuit04 from converging in 120 s).
#: 1 cm let a polish of male_casualsuit05 cross pieces; 3 mm: none of the suits' polishes.
FOLLOW_MOVE = 0.003

#: How often `_Newton.step` searches again with more held, while its trials make pieces cross.
HOLD_ROUNDS = 3


class ContactMode(str, enum.Enum):
    """How the body holds the garment up: cubic penalty on signed distances, or the IPC barrier."""

    PENALTY = "penalty"
    IPC = "ipc"


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
class _ContactState:
    """The penalty contact at one state. distance, normal: of every sample (vertices, then face
    centroids) (S,), (S, 3); inside: (S,) bool; energy: per garment (G,) [J]; grad: ∇E_c on the
    vertices (V, 3) [N]; contact: vertices in contact (V,) bool."""

    distance: Tensor
    normal: Tensor
    inside: Tensor
    energy: Tensor
    grad: Tensor
    contact: Tensor


class _Newton:
    """One `relax` call (arguments as `relax`; cloth in float64, body_index per garment)."""

    def __init__(self, x: Tensor, cloth: Cloth, bodies, body_index: Tensor, *, contact: ContactMode, tol: float,
                 energy_tol: float, contact_stiffness: float, margin: float, barrier_stiffness: float, dhat: float,
                 self_contact: bool, max_step: float, regularization: float, bend: BendHessian, try_exact: bool,
                 solver: LinearSolver, max_line_search: int) -> None:
        self.cloth, self.bodies = cloth, bodies
        self.tol, self.energy_tol, self.max_step, self.max_line_search = tol, energy_tol, max_step, max_line_search
        self.bend, self.try_exact, self.linear = bend, try_exact, _SparseSolver(solver)
        self.regularization = regularization
        self.num_garments = G = cloth.num_garments
        self.vg = vg = cloth.vert_garment
        self.vert_body = body_index[vg]
        self.weight = cloth.mass * cloth.gravity[vg].norm(dim=-1)  # m_i g [N]
        counts = torch.bincount(vg, minlength=G)
        offsets = [0] + torch.cumsum(counts, 0).tolist()
        self.asm = _Assembler(cloth.faces.numpy(), cloth.hinges.numpy(), cloth.num_verts)
        self.sample_garment = sample_index(vg, cloth.faces)  # owner of each contact sample (vertices, centroids)
        if contact is ContactMode.PENALTY:
            self.stiffness, self.margin = contact_stiffness, margin
            self.ipc = None
        else:  # the penalty term only flags contact (within d̂) and inside samples
            self.stiffness, self.margin = 0.0, dhat
            self.ipc = _IPCContact(x, cloth, bodies, body_index, offsets, stiffness=barrier_stiffness, dhat=dhat,
                                   self_contact=self_contact)
            self.ipc.check_start(x.numpy())
        # the regularisation in use and the schedule of exact-Hessian attempts (see `direction`)
        self.reg = regularization
        self.exact_wait, self.exact_backoff = 0, 1
        self.follows = cloth.layers is not None and cloth.layers.follows  # layer pairs found as it goes
        # a step may not carry a face of one piece through another piece (`oracle.crossings`)
        self.pieces = PieceGuard.of(cloth.faces, cloth.face_garment, cloth.num_verts, G)
        self.blocked = torch.zeros(cloth.num_verts, dtype=torch.bool)  # set by each `line_search`

    def follow_layers(self, x: Tensor) -> None:
        """Find the layer order's pairs again at x (`physics.layers.followed`; `self.follows`)."""
        self.cloth = replace(self.cloth, layers=followed(self.cloth.layers, x))

    # ----------------------------------------------------------------------------- energies
    def total_energy(self, x: Tensor, contact_energy_g: Tensor) -> tuple[Tensor, dict]:
        terms = energy_terms(x, self.cloth)  # strain, bend, gravity (and grip)
        total = sum(terms.values()) + contact_energy_g
        terms["contact"] = contact_energy_g
        return total, terms

    def contact_state(self, x: Tensor) -> _ContactState:
        faces = self.cloth.faces
        q = query_samples(x, faces, self.bodies, self.vert_body)
        distance, normal = q.signed_distance.to(x.dtype), q.normal.to(x.dtype)
        k, eps = self.stiffness, self.margin
        return _ContactState(
            distance=distance, normal=normal, inside=q.inside,
            energy=garment_energy(contact_energy(distance, stiffness=k, margin=eps), self.cloth),
            grad=-plane_contact_forces(x, faces, q.closest.to(x.dtype), normal, stiffness=k, margin=eps),
            contact=contact_vertices(distance, faces, margin=eps),
        )

    def trial_contact(self, x: Tensor) -> tuple[Tensor, Tensor]:
        """Per-garment contact energy (G,) and inside flags of the samples (S,) at a trial state."""
        q = query_samples(x, self.cloth.faces, self.bodies, self.vert_body)
        if self.ipc is not None:
            return torch.from_numpy(self.ipc.energy(x.numpy())), q.inside
        distance = q.signed_distance.to(x.dtype)
        return garment_energy(contact_energy(distance, stiffness=self.stiffness, margin=self.margin),
                              self.cloth), q.inside

    def gradient_state(self, x: Tensor):
        """(contact state, ∇E (V, 3), contact energy (G,), IPC Hessian or None, residual per garment
        over free vertices (G,), residual over all vertices (G,))."""
        st = self.contact_state(x)
        f = internal_forces(x, self.cloth)
        if self.ipc is None:
            grad_c, e_c, hess_c = st.grad, st.energy, None
        else:
            grad_np, hess_c = self.ipc.grad_hess(x.numpy(), project=not self.try_exact)
            grad_c = torch.from_numpy(grad_np)
            e_c = torch.from_numpy(self.ipc.energy(x.numpy()))
        grad = -f + grad_c
        res_v = grad.norm(dim=-1) / self.weight
        res_free = torch.where(~st.contact, res_v, torch.zeros_like(res_v))
        G, dt = self.num_garments, x.dtype
        res_g = torch.zeros(G, dtype=dt).scatter_reduce_(0, self.vg, res_free, reduce="amax")
        res_all_g = torch.zeros(G, dtype=dt).scatter_reduce_(0, self.vg, res_v, reduce="amax")
        return st, grad, e_c, hess_c, res_g, res_all_g

    # ----------------------------------------------------------------------------- the step
    def direction(self, x: Tensor, st: _ContactState, grad: Tensor, hess_c):
        """The Newton direction p (V, 3) and what produced it.

        With projection "auto", the exact Hessian is tried first (quadratic convergence near a
        minimum, where per-element projection over-stiffens compressed, buckled regions); when it
        is not positive definite the factorisation says so and the per-element PSD projection is
        used. After a failed exact attempt the next 1, 2, 4, … iterations skip it (reset on
        success): every failed factorisation costs a factorisation's time. The projected system's
        regularisation is raised ×100 until it factorises.

        Returns p, the lower-triangular matrix and its diagonal positions, the right-hand side,
        the regularisation used, whether the Hessian was projected, and the seconds spent on
        Hessians, assembly and solves.
        """
        cloth, dt = self.cloth, x.dtype
        t_h = t_a = t_s = 0.0
        rhs = -grad.numpy().reshape(-1)
        p = None
        projected = True
        attempts = [False, True] if self.try_exact and self.exact_wait == 0 else [True]
        self.exact_wait = max(self.exact_wait - 1, 0)
        for project in attempts:
            t0 = time.perf_counter()
            hs = strain_hessian(x, cloth, project=project)
            if self.bend is BendHessian.PROJECTED:
                hb = bend_hessian(x, cloth, project=project)
            else:
                hb = bend_gauss_newton_hessian(x, cloth)
            if self.ipc is None:
                hv, hf = contact_hessian_blocks(st.distance, st.normal, cloth.faces, stiffness=self.stiffness,
                                                margin=self.margin)
                hs = hs + hf
            else:
                hv = torch.zeros(cloth.num_verts, 3, 3, dtype=dt)
            if cloth.grip is not None:
                hv = hv + grip_blocks(cloth.grip, cloth.num_verts, dtype=dt)
            t1 = time.perf_counter()
            data = self.asm.assemble(hs.numpy(), hb.numpy(), hv.numpy())
            diag_mean = float(np.mean(data[self.asm.diag_pos]))
            if hess_c is not None and project and self.try_exact:  # the exact barrier Hessian was not PD
                hess_c = self.ipc.grad_hess(x.numpy(), project=True)[1]  # ipctk's projected one
            extra = _pair_hessian(x, cloth, hess_c)
            if extra is not None:
                lower = (self.asm.lower_matrix(data) + sp.tril(extra)).tocsc()
                lower.sort_indices()
                diag_pos = _diagonal_positions(lower)
            else:
                lower = self.asm.lower_matrix(data)  # sorted CSC, diagonal in the pattern
                diag_pos = self.asm.diag_pos
            base_diag = lower.data[diag_pos].copy()
            t2 = time.perf_counter()
            t_h, t_a = t_h + t1 - t0, t_a + t2 - t1
            if not project:  # exact Hessian: one try at the current regularisation
                lower.data[diag_pos] = base_diag + self.reg * diag_mean
                try:
                    with silenced(2):  # CHOLMOD may print a warning when it finds the matrix indefinite
                        p = self.linear.solve(lower, rhs)
                    reg_used, projected = self.reg, False
                    t_s += time.perf_counter() - t2
                    self.exact_backoff = 1
                    break
                except (ValueError, RuntimeError):
                    t_s += time.perf_counter() - t2
                    self.exact_wait, self.exact_backoff = self.exact_backoff, 2 * self.exact_backoff
                    continue
            while True:  # projected: raise the regularisation until the factorisation succeeds
                lower.data[diag_pos] = base_diag + self.reg * diag_mean
                try:
                    p = self.linear.solve(lower, rhs)
                    reg_used = self.reg
                    break
                except (ValueError, RuntimeError):
                    self.reg *= 100.0
                    if self.reg > 1e2:
                        raise RuntimeError("the Newton system stays singular even with a large regularisation; "
                                           "is every garment vertex in a face?") from None
            t_s += time.perf_counter() - t2
        p = torch.from_numpy(p).reshape(-1, 3)
        return p, lower, diag_pos, rhs, reg_used, projected, t_h, t_a, t_s

    def line_search(self, x: Tensor, p: Tensor, grad: Tensor, energy: Tensor, inside0: Tensor, skip: Tensor):
        """Backtracking Armijo per garment along p; garments in `skip` stay put.

        A trial that moves a vertex or a face centroid from outside the body to inside is
        rejected, and so is one that makes a face of a multi-piece garment intersect a face of
        another of its pieces where they did not (`PieceGuard`). Returns the new positions, the
        step lengths (G,), which garments accepted a step (G,) (skip counts as accepted) and each
        step's shrink factor against its first trial (G,).
        """
        cloth, vg, G, dt = self.cloth, self.vg, self.num_garments, x.dtype
        slope = cloth.sum_per_garment((grad * p).sum(-1), vg)  # (G,) < 0 for a descent direction
        descent = slope < 0
        if not bool(descent.all()):  # numerical trouble: steepest descent there
            p = torch.where(descent[vg][:, None], p, -grad / grad.norm(dim=-1).max().clamp_min(1e-300) * self.max_step)
            slope = cloth.sum_per_garment((grad * p).sum(-1), vg)
        pmax = torch.zeros(G, dtype=dt).scatter_reduce_(0, vg, p.norm(dim=-1), reduce="amax")
        alpha = torch.clamp(self.max_step / pmax.clamp_min(1e-300), max=1.0)
        if self.ipc is not None:
            ccd = torch.from_numpy(self.ipc.max_step(x.numpy(), (alpha[vg][:, None] * p).numpy()))
            alpha = alpha * torch.where(ccd >= 1.0, torch.ones_like(ccd), 0.9 * ccd)  # stay short of contact
        alpha0 = alpha.clone()
        accepted = skip.clone()
        x_new = x.clone()
        crossed = self.pieces.known(x) if self.pieces is not None else None
        self.blocked = torch.zeros(x.shape[0], dtype=torch.bool)  # corners of the faces a trial made cross
        for _ in range(self.max_line_search):
            trial = x + alpha[vg][:, None] * p
            e_c_t, inside_t = self.trial_contact(trial)
            e_t, _ = self.total_energy(trial, e_c_t)
            new_inside = (inside_t & ~inside0).to(torch.int64)
            bad = torch.zeros(G, dtype=torch.int64).index_add_(0, self.sample_garment, new_inside) > 0
            ok = (e_t <= energy + 1e-4 * alpha * slope) & ~bad & ~accepted
            if crossed is not None and bool((ok & self.pieces.multi).any()):
                fresh = self.pieces.new_pairs(trial, crossed)
                if len(fresh):
                    crossing = self.pieces.garments(fresh) & ok
                    ok &= ~crossing
                    self.blocked |= self.pieces.vertices(fresh, x.shape[0]) & crossing[vg]
            if bool(ok.any()):
                take = ok[vg]
                x_new[take] = trial[take]
                accepted |= ok
            if bool(accepted.all()):
                break
            alpha = torch.where(accepted, alpha, 0.5 * alpha)
        return x_new, alpha, accepted, alpha / alpha0

    def step(self, x: Tensor, st: _ContactState, grad: Tensor, energy: Tensor, done: Tensor, p: Tensor,
             lower, diag_pos, rhs: np.ndarray) -> tuple[Tensor, Tensor, bool]:
        """Line search along p, per garment; garments in `done` stay put. Where it finds no step,
        or only one backtracked more than ten times (the penalty's distance field has kinks where
        the closest body feature switches, e.g. in concave regions), a Newton step on the vertices
        out of contact, contact vertices held, is searched instead, with the corners of the faces
        that the rejected trials made cross another piece held too (`PieceGuard`; as often as
        that holds more, up to `HOLD_ROUNDS` times). Returns the new positions, the step lengths
        (G,) (0 where none was taken) and whether any garment moved."""
        vg = self.vg
        x_new, alpha, accepted, shrink = self.line_search(x, p, grad, energy, st.inside, done)
        held = st.contact | self.blocked
        for _ in range(HOLD_ROUNDS):
            failed = (~accepted | (shrink < 1e-3)) & ~done
            fixed = held | ~failed[vg]
            if not bool(failed.any()) or bool(fixed.all()):
                break
            p_free = torch.from_numpy(_solve_fixed(lower, diag_pos, rhs, fixed.numpy(), self.linear)).reshape(-1, 3)
            x_free, alpha_free, acc_free, _ = self.line_search(x, p_free, grad, energy, st.inside, ~failed)
            take = (acc_free & failed)
            x_new[take[vg]] = x_free[take[vg]]
            alpha = torch.where(take, alpha_free, alpha)
            shrink = torch.where(take, torch.ones_like(shrink), shrink)
            accepted |= take
            if not bool((self.blocked & ~held).any()):
                break  # nothing more to hold: another round would search the same step
            held = held | self.blocked
        alpha = torch.where(accepted & ~done, alpha, torch.zeros_like(alpha))
        return x_new, alpha, bool((accepted & ~done).any())

    # ----------------------------------------------------------------------------- the loop
    def run(self, x: Tensor, *, max_iters: int, time_budget_s: float | None, callback, t_start: float):
        """Iterate from x (ΣV, 3) float64 until converged or out of budget: (x, terms, energy (G,),
        history, timings, reason, converged, residual (G,))."""
        G, dt, tol, energy_tol = self.num_garments, x.dtype, self.tol, self.energy_tol
        if self.follows:
            self.follow_layers(x)
        searched = x  # where the layer pairs were last searched
        st, grad, e_c, hess_c, res_g, res_all_g = self.gradient_state(x)
        energy, terms = self.total_energy(x, e_c)
        history = [IterationRecord(0, float(energy.sum()), math.nan, float(res_g.max()), float(res_all_g.max()), 0.0,
                                   int(st.contact.sum()), int(st.inside.sum()), wall=time.perf_counter() - t_start)]
        if callback is not None:
            callback(history[-1], x)
        timings = {"hessian": 0.0, "assembly": 0.0, "solve": 0.0, "line_search": 0.0}
        reason, converged = "max_iters", False
        change_g = torch.full((G,), math.inf, dtype=dt)
        for it in range(1, max_iters + 1):
            if self.follows and float((x - searched).norm(dim=-1).max()) > FOLLOW_MOVE:
                self.follow_layers(x)
                searched = x  # the pieces moved: the pairs where they are change the energy
                st, grad, e_c, hess_c, res_g, res_all_g = self.gradient_state(x)
                energy, terms = self.total_energy(x, e_c)
            if bool((res_g < tol).all()) and bool((change_g < energy_tol).all()):
                reason, converged = "converged", True
                break
            if time_budget_s is not None and time.perf_counter() - t_start > time_budget_s:
                reason = "time_budget"
                break
            p, lower, diag_pos, rhs, reg_used, projected, t_h, t_a, t_s = self.direction(x, st, grad, hess_c)
            t3 = time.perf_counter()
            t0, t1, t2 = t3 - (t_h + t_a + t_s), t3 - (t_a + t_s), t3 - t_s
            done = (res_g < tol) & (change_g < energy_tol)  # converged garments stay put
            x, alpha, progressed = self.step(x, st, grad, energy, done, p, lower, diag_pos, rhs)
            t4 = time.perf_counter()
            timings["hessian"] += t1 - t0
            timings["assembly"] += t2 - t1
            timings["solve"] += t3 - t2
            timings["line_search"] += t4 - t3
            st, grad, e_c, hess_c, res_g, res_all_g = self.gradient_state(x)
            energy_old = energy
            energy, terms = self.total_energy(x, e_c)
            change_g = (energy_old - energy).abs() / energy.abs().clamp_min(1e-300)
            self.reg = max(self.regularization, self.reg / 10.0)
            history.append(IterationRecord(it, float(energy.sum()), float(change_g.max()), float(res_g.max()),
                                           float(res_all_g.max()), float(alpha.min()), int(st.contact.sum()),
                                           int(st.inside.sum()), reg_used, projected, t1 - t0, t2 - t1, t3 - t2,
                                           t4 - t3, time.perf_counter() - t_start))
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
        return x, terms, energy, history, timings, reason, converged, res_g


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
        contact: "penalty" (`physics.contact`: k_c ReLU(ε − d)³ at the vertices and face centroids,
            `contact_stiffness` k_c [J/m³], `margin` ε [m]) or "ipc" (ipctk barrier,
            `barrier_stiffness` κ, `dhat` d̂ [m], CCD-clipped steps; needs ``pip install ipctk``;
            `self_contact` adds garment–garment barrier pairs).
        tol: residual tolerance: max over vertices not in contact of ‖F_int + F_contact‖ / (m_i g).
        energy_tol: relative energy change tolerance |ΔE_g| / |E_g| over the last iteration (both must
            hold; E_g includes gravity, so it depends on the height of the origin — y = 0 at the
            body's feet or centre keeps it meaningful).
        max_iters, time_budget_s: iteration and wall-time [s] budgets.
        max_step: largest vertex displacement of one Newton step [m].
        regularization: diagonal term added to the Hessian, relative to its mean diagonal
            (raised ×100 until the factorisation succeeds).
        bend: "gauss_newton" (k∇θ∇θᵀ, analytic, PSD; default: fewer iterations to the tolerance)
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
    if x0.ndim != 2 or x0.shape != (cloth.num_verts, 3):
        raise ValueError(f"x0 must be packed positions of shape ({cloth.num_verts}, 3) like the cloth, "
                         f"got {tuple(x0.shape)}")
    if not torch.isfinite(x0).all():
        raise ValueError("x0 contains NaN/inf")
    if {x0.device.type, cloth.device.type, bodies.device.type} != {"cpu"}:
        raise ValueError(f"relax runs on the CPU (scipy's sparse factorisations), got x0 on {x0.device}, the cloth on "
                         f"{cloth.device} and the bodies on {bodies.device}: move them there (x0.cpu(), "
                         "cloth.to(device='cpu'), bodies.to('cpu'))")
    G = cloth.num_garments
    body_index = torch.zeros(G, dtype=torch.int64) if body_index is None else torch.as_tensor(body_index).long()
    if body_index.shape != (G,):
        raise ValueError(f"body_index must have one entry per garment ({G},), got {tuple(body_index.shape)}")
    if int(body_index.min()) < 0 or int(body_index.max()) >= bodies.batch_size:
        raise ValueError(f"indices in body_index must be in [0, {bodies.batch_size}) (got {body_index.tolist()})")

    x = x0.detach().to(torch.float64).clone()
    newton = _Newton(x, _cloth_to(cloth, torch.float64), bodies, body_index, contact=contact, tol=tol,
                     energy_tol=energy_tol, contact_stiffness=contact_stiffness, margin=margin,
                     barrier_stiffness=barrier_stiffness, dhat=dhat, self_contact=self_contact, max_step=max_step,
                     regularization=regularization, bend=bend, try_exact=try_exact, solver=solver,
                     max_line_search=max_line_search)
    x, terms, energy, history, timings, reason, converged, residual = newton.run(
        x, max_iters=max_iters, time_budget_s=time_budget_s, callback=callback, t_start=t_start)
    terms = {k: v.detach() for k, v in terms.items()}
    terms["total"] = energy.detach()
    return OracleResult(x=x.to(x0.dtype), energy_terms=terms, history=history, converged=converged, reason=reason,
                        residual=residual, wall_time=time.perf_counter() - t_start, timings=timings)


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

"""What `relax` returns: one record per Newton iteration and the result of a call."""

from __future__ import annotations

from dataclasses import dataclass, field

from torch import Tensor


@dataclass(frozen=True)
class IterationRecord:
    """One Newton iteration (iteration 0 = the start state; its times are zero).

    energy: total energy summed over garments [J]; energy_change: max over garments of
    |ΔE_g| / |E_g| for this iteration; residual: max over garments and over vertices not in
    contact of ‖F‖ / (m_i g); residual_all: the same over all vertices; step: min over garments of
    the accepted step length; num_contact: vertices in contact (themselves or through a face's
    centroid); num_inside: vertices and face centroids inside the body (BodySurface's inside
    test); regularization: the diagonal shift used, relative to the mean diagonal of the Hessian;
    projected: whether the element Hessians were projected to PSD (False: the exact Hessian was
    positive definite); t_hessian, t_assembly, t_solve, t_line_search: seconds spent in each
    phase; wall: seconds since the start of `relax`.
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

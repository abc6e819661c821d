"""A drape's convergence record: the solver's trace as energy and force per garment and step
(`DrapeResult.convergence`, `Draper.drape(keep_trace=True)`)."""

from __future__ import annotations

from physdrape.physics import energy_terms, internal_forces


def solver_convergence(out, inp, count: int) -> list[dict[str, list[float]]]:
    """Per garment of a batch of `count`, the energy E_strain + E_bend + E_grav [J] and the total
    force Σ‖F_int + f̂‖ [N] after each solver step t = 0 … T, from the model's output `out` (its
    x_gnn and trace) on the input `inp`."""
    convergence: list[dict[str, list[float]]] = [{"energy": [], "force": []} for _ in range(count)]
    for xt in (out.x_gnn, *out.trace):
        e = sum(energy_terms(xt, inp.cloth).values())
        f = (internal_forces(xt, inp.cloth) + out.f_hat).norm(dim=-1)
        fsum = f.new_zeros(count).index_add_(0, inp.garments.vert_garment, f)
        for k in range(count):
            convergence[k]["energy"].append(float(e[k]))
            convergence[k]["force"].append(float(fsum[k]))
    return convergence

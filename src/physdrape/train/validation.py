"""The held-out learning curve: the model's rows on a fixed validation set, against the teacher.

Every `OptimConfig.validate_every` steps the trainer drapes the instance cache's validation
instances (garments and bodies never trained on) with the current weights and logs, per row:

- ``energy_ratio``: the mean E_total over the set divided by the teacher drapes' mean E_total (the
  two-level solver run to near convergence from the same X_init; `physdrape.train.instances`),
  the measure of `physdrape eval`;
- ``energy_gap``: the fraction of X_init's excess E_total over the teacher's that the row leaves,
  (ΣE_row − ΣE_teacher) / (ΣE_init − ΣE_teacher): 1 at X_init, 0 at the teacher. Unlike the
  ratio it does not depend on where the height origin of E_grav lies;
- ``strain_ratio``: the same ratio as energy_ratio for E_strain; ``b2g_percent``.

Rows, as in `physdrape eval`:

- ``gnn``: X_init + Δx, no solver, no handler (what the network alone does);
- ``t3`` / ``t15``: the full model with T = 3 / 15 solver steps and the handler;
- ``solver_t3`` / ``solver_t15``: the same without the network (Δx = 0, f̂ = 0), computed once:
  what the network adds is the difference to ``t3`` / ``t15``.
"""

from __future__ import annotations

from dataclasses import replace

import torch

from physdrape.model import PhysDrape, Variant
from physdrape.physics.energy import drape_energies, total_energy
from physdrape.physics.metrics import b2g_percent
from physdrape.train.data import TrainingBatch

#: Row name → (variant, solver steps, with the network).
ROWS = {
    "gnn": (Variant.GNN_ONLY, 0, True),
    "t3": (Variant.FULL, 3, True),
    "t15": (Variant.FULL, 15, True),
    "solver_t3": (Variant.FULL, 3, False),
    "solver_t15": (Variant.FULL, 15, False),
}
NETWORK_FREE = ("solver_t3", "solver_t15")


class Validator:
    """Drapes `batches` (one instance each, with their teacher drapes) with a model's weights."""

    def __init__(self, batches: list[TrainingBatch]) -> None:
        if any(b.teacher is None for b in batches):
            raise ValueError("validation needs the teacher drapes of an instance cache")
        self.batches = batches
        self._fixed: dict[str, float] | None = None

    @torch.no_grad()
    def __call__(self, model: PhysDrape) -> dict[str, float]:
        """{"<row>/energy_ratio", "<row>/energy_gap", "<row>/strain_ratio", "<row>/b2g_percent"} for every row; the
        network-free rows are computed on the first call only (they do not change in training)."""
        if not self.batches:
            return {}
        rows = [r for r in ROWS if r not in NETWORK_FREE or self._fixed is None]
        out = self._rows(model, rows)
        if self._fixed is None:
            self._fixed = {k: v for k, v in out.items() if k.split("/")[0] in NETWORK_FREE}
        return {**out, **self._fixed}

    def _rows(self, model: PhysDrape, rows: list[str]) -> dict[str, float]:
        state = model.state_dict()
        dtype = model.gnn.decoder[0].weight.dtype
        contact = dict(contact_stiffness=model.config.contact_stiffness, margin=model.config.margin)
        teacher_total = teacher_strain = init_total = 0.0
        sums = {r: [0.0, 0.0, 0.0] for r in rows}
        variants = {}
        for variant in {ROWS[r][0] for r in rows}:
            variants[variant] = PhysDrape(replace(model.config, variant=variant)).to(dtype).eval()
            variants[variant].load_state_dict(state)
        for batch in self.batches:
            drape = batch.drape
            problem = (drape.cloth, drape.bodies, drape.body_index)
            teacher_total += float(total_energy(batch.teacher, *problem, **contact)[0])
            init_total += float(total_energy(drape.x_init, *problem, **contact)[0])
            teacher_strain += float(drape_energies(batch.teacher, *problem, **contact)["strain"][0])
            for r in rows:
                variant, steps, network = ROWS[r]
                m = variants[variant]
                x = (m(drape, steps=steps) if network else m.physics_only(drape, steps=steps)).x
                terms = drape_energies(x, *problem, **contact)
                sums[r][0] += float(sum(terms.values())[0])
                sums[r][1] += float(terms["strain"][0])
                sums[r][2] += float(b2g_percent(x, drape.garments, drape.bodies, drape.body_index)[0])
        out = {}
        for r, (total, strain, b2g) in sums.items():
            out[f"{r}/energy_ratio"] = total / teacher_total
            out[f"{r}/energy_gap"] = (total - teacher_total) / (init_total - teacher_total)
            out[f"{r}/strain_ratio"] = strain / teacher_strain
            out[f"{r}/b2g_percent"] = b2g / len(self.batches)
        return out

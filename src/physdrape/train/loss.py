"""The self-supervised loss (paper Sec. 3.6): L = E_strain + E_bend + E_coll + E_grav at X*, plus
optionally a pull toward the physics teacher's drape (`physdrape.train.instances`)."""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from physdrape.geometry.proximity import BodySurface
from physdrape.model.config import ModelConfig
from physdrape.physics.cloth import Cloth
from physdrape.physics.coarse_space import CoarseSpace
from physdrape.physics.energy import drape_energies
from physdrape.train.instances import teacher_solver


@dataclass(frozen=True)
class LossConfig:
    """per_garment_scale: "none" (the paper: energies in J, averaged over the batch) or "initial":
    each garment's energy is divided by a constant (no gradient) of its own, its elastic energy
    E_strain + E_bend + E_coll at X_init plus its weight × 1 cm, so that a garment starting
    hundreds of joules from equilibrium (an extreme shape or pose) does not steer the whole batch.

    The contact term's stiffness k_c and margin ε are the model's (`ModelConfig.contact_stiffness`,
    `ModelConfig.margin`), so the loss and the solver's contact term are one term.

    teacher_weight [J/m²]: adds, per garment, teacher_weight × the mass-weighted mean squared
    distance [m²] of the drape to the teacher's (the two-level solver run to near convergence
    from the same X_init). The energy alone tells each vertex which way is downhill; the teacher
    also says how far the garment as a whole still has to settle, which a few solver steps in the
    loop cannot show. 0 = the paper's loss (and no teacher needed).

    teacher_levels: 0 compares the drape with the teacher vertex by vertex; L > 0 compares only
    the smooth part of their difference, its least-squares fit on the patches of the solver's
    coarse space at level L (`CoarseSpace.fit`; 2: patches of 6–15 vertices). The teacher then
    says where the garment as a whole should go and leaves each vertex's local settling to the
    energy: the solver relaxes the local strain within a few steps, not the garment-wide slide.

    lookahead_weight [J/m²] and lookahead_steps: adds, per garment, lookahead_weight × the
    mass-weighted mean squared distance [m²] of the drape to where `lookahead_steps` steps of the
    teacher's solver take it from there (computed without gradient by the trainer,
    `lookahead_target`). Its gradient on a vertex is the solver's preconditioned step from the
    drape, scaled by the vertex's mass: where the energy's gradient is dominated by the stiff
    strain modes, this one carries the soft, garment-wide moves the preconditioner's coarse level
    makes. Its only fixed point is a drape the solver does not move, an equilibrium; physics alone
    makes the target. 0 = off (the shipped recipe's choice: docs/training/README.md says what the
    term gave).

    earlier_passes_weight: with `ModelConfig.passes` > 1, adds per garment this weight × the energy
    (the same terms, scaled alike) at each earlier pass's drape X_init + Δx (`DrapeOutput.
    earlier_passes`). Trained through the last pass's move only, the first pass stops draping on
    its own and leaves the work to the later ones; with the term every pass learns to drape, the
    later ones from where the earlier left the garment. 0 = the loss at the last drape only.

    distill_weight [J/m²] and distill_passes: adds, per garment, distill_weight × the
    mass-weighted mean squared distance [m²] of the drape to the drape that the network the run
    starts from (`OptimConfig.init_from`, frozen) makes as distill_passes passes without the
    solver (`physdrape.train.distill`): one pass learns what the same weights reach in several.
    0 = off. distill_levels: as teacher_levels, for this term (L > 0: only the smooth part of the
    difference, the garment-wide move, is pulled; the energy alone shapes the local one).
    """

    per_garment_scale: str = "none"
    teacher_weight: float = 0.0
    teacher_levels: int = 0
    lookahead_weight: float = 0.0
    lookahead_steps: int = 3
    earlier_passes_weight: float = 0.0
    distill_weight: float = 0.0
    distill_passes: int = 2
    distill_levels: int = 0

    def __post_init__(self) -> None:
        if self.per_garment_scale not in ("none", "initial"):
            raise ValueError(f"LossConfig.per_garment_scale must be 'none' or 'initial', got {self.per_garment_scale!r}")
        if not self.teacher_weight >= 0:
            raise ValueError(f"LossConfig.teacher_weight must be ≥ 0 [J/m²], got {self.teacher_weight!r}")
        if not isinstance(self.teacher_levels, int) or self.teacher_levels < 0:
            raise ValueError(f"LossConfig.teacher_levels must be an integer ≥ 0 (0: vertex by vertex, L: the fit "
                             f"on the coarse patches of level L), got {self.teacher_levels!r}")
        if not self.lookahead_weight >= 0 or self.lookahead_steps < 1:
            raise ValueError(f"LossConfig needs lookahead_weight ≥ 0 [J/m²] and lookahead_steps ≥ 1, got "
                             f"{self.lookahead_weight!r} and {self.lookahead_steps!r}")
        if not self.earlier_passes_weight >= 0:
            raise ValueError(f"LossConfig.earlier_passes_weight must be ≥ 0, got {self.earlier_passes_weight!r}")
        if not self.distill_weight >= 0 or not isinstance(self.distill_passes, int) or self.distill_passes < 2:
            raise ValueError(f"LossConfig needs distill_weight ≥ 0 [J/m²] and an integer distill_passes ≥ 2 (the "
                             f"teacher's passes), got {self.distill_weight!r} and {self.distill_passes!r}")
        if not isinstance(self.distill_levels, int) or self.distill_levels < 0:
            raise ValueError(f"LossConfig.distill_levels must be an integer ≥ 0 (as teacher_levels), got "
                             f"{self.distill_levels!r}")


def teacher_distance(x: Tensor, teacher: Tensor, cloth: Cloth, levels: int = 0) -> Tensor:
    """Mass-weighted mean squared distance of x to the teacher drape per garment [m²] (G,); with
    `levels` > 0, of the fit of x − teacher on the coarse patches of that level (`LossConfig`)."""
    difference = x - teacher
    if levels > 0:
        difference = CoarseSpace(cloth, levels=levels).fit(difference)
    weighted = cloth.mass * difference.pow(2).sum(-1)
    return cloth.sum_per_garment(weighted, cloth.vert_garment) / cloth.sum_per_garment(cloth.mass, cloth.vert_garment)


@torch.no_grad()
def lookahead_target(x: Tensor, cloth: Cloth, bodies: BodySurface, body_index: Tensor, config: LossConfig,
                     model: ModelConfig) -> Tensor:
    """Where `config.lookahead_steps` steps of the teacher's solver (`instances.teacher_solver`:
    the two-level solver with the product's settings and the model's contact term) take the
    drape x (ΣV, 3) [m] without the network's forces; no gradient."""
    solver = teacher_solver(model).to(device=x.device)
    return solver(x.detach(), cloth, f_hat=None, steps=config.lookahead_steps, bodies=bodies, body_index=body_index)


def drape_loss(x: Tensor, cloth: Cloth, bodies: BodySurface, body_index: Tensor, config: LossConfig,
               x_init: Tensor | None = None, *, contact_stiffness: float, margin: float,
               teacher: Tensor | None = None, lookahead: Tensor | None = None,
               earlier_passes: tuple[Tensor, ...] = (),
               distill: Tensor | None = None) -> tuple[Tensor, dict[str, Tensor]]:
    """The training loss: the sum of the terms per garment (divided by the garment's scale when
    `config.per_garment_scale` is "initial", which needs x_init), plus the teacher term when
    `config.teacher_weight` > 0 (which needs `teacher`, (ΣV, 3) [m]) and the lookahead term when
    `config.lookahead_weight` > 0 (which needs `lookahead`, (ΣV, 3) [m], see `lookahead_target`),
    averaged over the batch.
    contact_stiffness [J/m³], margin [m]: the contact term's k_c and ε (see `drape_energies`).

    Returns the scalar loss and the batch-mean of each term [J] (detached) for logging, with the
    teacher distance as "teacher_rms" [m] when a teacher is given and the lookahead distance as
    "lookahead_rms" [m] when a lookahead target is. earlier_passes: the earlier passes' drapes
    (`DrapeOutput.earlier_passes`), whose energies `config.earlier_passes_weight` adds (logged as
    "earlier_passes" [J], the mean over them). distill: the teacher network's drape (ΣV, 3) [m]
    (`physdrape.train.distill.PassesTeacher`), needed when `config.distill_weight` > 0 (its
    distance logged as "distill_rms" [m]).
    """
    contact = {"contact_stiffness": contact_stiffness, "margin": margin}
    terms = drape_energies(x, cloth, bodies, body_index, **contact)
    total = sum(terms.values())
    if config.earlier_passes_weight > 0 and earlier_passes:
        earlier = torch.stack([sum(drape_energies(xk, cloth, bodies, body_index, **contact).values())
                               for xk in earlier_passes])
        total = total + config.earlier_passes_weight * earlier.sum(0)
    if config.per_garment_scale == "initial":
        if x_init is None:
            raise ValueError("per_garment_scale='initial' needs x_init")
        with torch.no_grad():
            start = drape_energies(x_init, cloth, bodies, body_index, **contact)
            weight = cloth.sum_per_garment(cloth.mass, cloth.vert_garment) * cloth.gravity.norm(dim=-1)
            scale = start["strain"] + start["bend"] + start["collision"] + 0.01 * weight
        total = total / scale
    logged = {name: value.detach().mean() for name, value in terms.items()}
    if config.earlier_passes_weight > 0 and earlier_passes:
        logged["earlier_passes"] = earlier.detach().mean()
    if config.teacher_weight > 0 and teacher is None:
        raise ValueError("LossConfig.teacher_weight > 0 needs the teacher drapes of an instance cache: set "
                         "data.instances to a folder (built on first use)")
    if teacher is not None:
        distance = teacher_distance(x, teacher, cloth, config.teacher_levels)
        logged["teacher_rms"] = distance.detach().mean().sqrt()
        if config.teacher_weight > 0:
            total = total + config.teacher_weight * distance
    if config.lookahead_weight > 0 and lookahead is None:
        raise ValueError("LossConfig.lookahead_weight > 0 needs the lookahead target (`lookahead_target`)")
    if lookahead is not None:
        distance = teacher_distance(x, lookahead, cloth)
        logged["lookahead_rms"] = distance.detach().mean().sqrt()
        total = total + config.lookahead_weight * distance
    if config.distill_weight > 0 and distill is None:
        raise ValueError("LossConfig.distill_weight > 0 needs the teacher network's drape (`train.distill`)")
    if distill is not None:
        distance = teacher_distance(x, distill, cloth, config.distill_levels)
        logged["distill_rms"] = distance.detach().mean().sqrt()
        total = total + config.distill_weight * distance
    return total.mean(), logged

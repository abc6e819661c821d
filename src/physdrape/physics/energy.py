"""The static energy of a drape on its body: what the loss, the oracle and the metrics measure."""

from __future__ import annotations

from dataclasses import replace

from torch import Tensor

from physdrape.geometry.proximity import BodySurface
from physdrape.physics.cloth import Cloth
from physdrape.physics.contact import penalty_contact_energy
from physdrape.physics.forces import energy_terms
from physdrape.physics.layers import followed


def drape_energies(x: Tensor, cloth: Cloth, bodies: BodySurface, body_index: Tensor, *, contact_stiffness: float,
                   margin: float) -> dict[str, Tensor]:
    """Each energy term per garment [J] at positions x (ΣV, 3) [m]: {strain, bend, collision, gravity}
    (and grip, stitch and layer when the cloth has them: `physics.grip`, `physics.stitches`,
    `physics.layers`) → (G,).

    body_index: body of each vertex (ΣV,). collision is the contact penalty of `physics.contact`
    (k_c = contact_stiffness [J/m³], ε = margin [m]) at the vertices and the face centroids, the
    oracle's term. A layer order that follows the pieces (`LayerOrder.follows`) is measured with
    its pairs found at x (`physics.layers.followed`), as the oracle minimises it.
    """
    if cloth.layers is not None and cloth.layers.follows:
        cloth = replace(cloth, layers=followed(cloth.layers, x))
    terms = energy_terms(x, cloth)
    out = {
        "strain": terms["strain"],
        "bend": terms["bend"],
        "collision": penalty_contact_energy(x, cloth, bodies, body_index, stiffness=contact_stiffness, margin=margin),
        "gravity": terms["gravity"],
    }
    for extra in ("grip", "stitch", "layer"):
        if extra in terms:
            out[extra] = terms[extra]
    return out


def total_energy(x: Tensor, cloth: Cloth, bodies: BodySurface, body_index: Tensor, *, contact_stiffness: float,
                 margin: float) -> Tensor:
    """E_strain + E_bend + E_grav + E_contact (+ E_grip + E_stitch + E_layer) per garment [J] (G,): the sum of `drape_energies`,
    the energy the oracle minimises."""
    return sum(drape_energies(x, cloth, bodies, body_index, contact_stiffness=contact_stiffness,
                              margin=margin).values())

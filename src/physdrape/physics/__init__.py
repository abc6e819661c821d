"""Physics of the garment: material, energies and their analytic forces (pure, batched, any dtype)."""

from physdrape.physics.bending import bend_energy, bend_forces, dihedral_angle
from physdrape.physics.cloth import Cloth
from physdrape.physics.contact import contact_energy, penalty_contact_energy, plane_contact_forces
from physdrape.physics.forces import energy_terms, internal_energy, internal_forces
from physdrape.physics.gravity import gravity_energy, gravity_forces
from physdrape.physics.material import DEFAULT_MATERIAL, Material
from physdrape.physics.oracle import OracleResult, relax
from physdrape.physics.strain import strain_energy, strain_forces

__all__ = [
    "Cloth",
    "DEFAULT_MATERIAL",
    "Material",
    "OracleResult",
    "bend_energy",
    "bend_forces",
    "contact_energy",
    "dihedral_angle",
    "energy_terms",
    "gravity_energy",
    "gravity_forces",
    "internal_energy",
    "internal_forces",
    "penalty_contact_energy",
    "plane_contact_forces",
    "relax",
    "strain_energy",
    "strain_forces",
]

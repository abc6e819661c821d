"""The learned model: features, normalisers, the force-driven GNN, solver, collision handler."""

from physdrape.model.config import Displacement, ModelConfig, Variant
from physdrape.model.physdrape import DrapeInput, DrapeOutput, PhysDrape

__all__ = ["Displacement", "DrapeInput", "DrapeOutput", "ModelConfig", "PhysDrape", "Variant"]

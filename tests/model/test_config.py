"""ModelConfig: the defaults are the shipped model's physics settings, and its config loads strictly."""

import json
from importlib import resources

import pytest

from physdrape.config_io import from_mapping
from physdrape.model import ModelConfig
from physdrape.model.stretching_solver import SolverKind

PHYSICS = ("solver", "eta", "gamma", "max_step", "requery_every", "coarse_levels", "coarse_smoothing", "delta",
           "margin", "contact_stiffness", "centroid_margin", "train_steps", "eval_steps", "displacement_scale")


def _shipped() -> dict:
    path = resources.files("physdrape") / "assets" / "models" / "cpu_default" / "config.json"
    return json.loads(path.read_text())["train"]["model"]


def test_the_shipped_models_config_loads_strictly():
    config = from_mapping(ModelConfig, _shipped(), where="cpu_default/config.json:train.model")
    assert config.solver is SolverKind.TWO_LEVEL


def test_defaults_are_the_shipped_models_physics_settings():
    shipped, default = from_mapping(ModelConfig, _shipped()), ModelConfig()
    assert {name: getattr(default, name) for name in PHYSICS} == {name: getattr(shipped, name) for name in PHYSICS}


def test_solver_schedule_fields_are_checked():
    """f_hat_steps: an integer ≥ 0 or null (every step); eval_requery_every ≥ 1; follow_min_move ≥ 0 [m]."""
    for bad in (-1, "3", True, 2.5):
        with pytest.raises(ValueError, match="f_hat_steps"):
            ModelConfig(f_hat_steps=bad)
    with pytest.raises(ValueError, match="eval_requery_every"):
        ModelConfig(eval_requery_every=0)
    for bad in (-1e-3, float("nan")):
        with pytest.raises(ValueError, match="follow_min_move"):
            ModelConfig(follow_min_move=bad)
    assert ModelConfig(f_hat_steps=None).f_hat_steps is None and ModelConfig().f_hat_steps == ModelConfig().train_steps


def test_contact_band_reaches_the_solver_and_is_checked():
    """contact_band [m] > 0 is the two-level solver's contact band (its preconditioner's and its followed planes')."""
    from physdrape.model.physdrape import PhysDrape

    assert PhysDrape(ModelConfig(latent=8, blocks=2, contact_band=0.005)).solver.contact_band == 0.005
    for bad in (0.0, -1e-3, float("nan")):
        with pytest.raises(ValueError, match="contact_band"):
            ModelConfig(contact_band=bad)


def test_eval_contact_band_reaches_the_solver_and_is_checked():
    from physdrape.model.physdrape import PhysDrape

    solver = PhysDrape(ModelConfig(latent=8, blocks=2, eval_contact_band=0.005)).solver
    assert (solver.contact_band, solver.eval_contact_band) == (0.01, 0.005)
    assert PhysDrape(ModelConfig(latent=8, blocks=2, eval_contact_band=None)).solver.eval_contact_band == 0.01
    assert ModelConfig().eval_contact_band == 0.007  # the bundled model's config.json predates the field
    with pytest.raises(ValueError, match="eval_contact_band"):
        ModelConfig(eval_contact_band=0.0)

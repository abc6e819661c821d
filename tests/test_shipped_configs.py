"""Every run config and recipe under configs/ loads with the strict config checks (a field
renamed or removed in the code would otherwise surface only when someone runs that config)."""

from pathlib import Path

import pytest

from physdrape.config_io import load_config
from physdrape.train.recipe import load_recipe, stage_configs
from physdrape.train.trainer import TrainConfig

CONFIGS = Path(__file__).resolve().parents[1] / "configs"
RUN_CONFIGS = sorted(p for p in CONFIGS.rglob("*.yaml") if p.parent.name != "recipes")


def test_there_are_configs_to_check():
    assert len(RUN_CONFIGS) >= 10 and (CONFIGS / "recipes" / "shipped.yaml").is_file()


@pytest.mark.parametrize("path", RUN_CONFIGS, ids=lambda p: str(p.relative_to(CONFIGS)))
def test_run_config_loads(path):
    config = load_config(TrainConfig, path)
    assert config.optim.steps > 0


@pytest.mark.parametrize("path", sorted((CONFIGS / "recipes").glob("*.yaml")), ids=lambda p: p.name)
def test_recipe_and_its_stages_load(path, tmp_path):
    stages = stage_configs(load_recipe(path), tmp_path)
    assert stages and all(isinstance(stage, TrainConfig) for stage in stages)

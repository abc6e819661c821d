"""Training recipes: stages run in order, each from the last; an interrupted recipe resumes; the
last stage is shipped with its record."""

from __future__ import annotations

import json

import pytest
import torch
import yaml

from physdrape import checkpoint as ckpt
from physdrape.config_io import ConfigError, to_mapping
from physdrape.model import ModelConfig, Variant
from physdrape.train.recipe import load_recipe, run_recipe
from physdrape.train.synthetic import SyntheticSource
from physdrape.train.trainer import OptimConfig, TrainConfig


def _config(path, *, solver: str, steps: int, seed: int, zero: bool = False, init_from: str = ""):
    model = ModelConfig(latent=8, blocks=1, normalizer_accumulations=2, solver=solver, zero_init_output=zero)
    config = TrainConfig(model=model, optim=OptimConfig(steps=steps, batch_size=2, lr=1e-3, checkpoint_every=2,
                                                        log_every=1, seed=seed, init_from=init_from))
    path.write_text(yaml.safe_dump(to_mapping(config)))
    return path


@pytest.fixture
def recipe(tmp_path):
    first = _config(tmp_path / "a.yaml", solver="explicit", steps=4, seed=1)
    second = _config(tmp_path / "b.yaml", solver="two_level", steps=3, seed=2, zero=True,
                     init_from="replaced/by/the/recipe")
    path = tmp_path / "recipe.yaml"
    path.write_text(yaml.safe_dump({"stages": [{"name": "one", "config": str(first)},
                                               {"name": "two", "config": str(second)}],
                                    "ship": {"model_out": str(tmp_path / "model"),
                                             "record_out": str(tmp_path / "record")}}))
    return path


def source(_config):
    return SyntheticSource()


def test_stages_chain_resume_and_ship(recipe, tmp_path):
    run = tmp_path / "run"
    record = run_recipe(recipe, run, source=source, command="physdrape train --recipe r", log=lambda _: None)
    assert [s["name"] for s in record["stages"]] == ["one", "two"]
    assert record["stages"][0]["init_from"] == ""  # the first stage's own setting: random weights
    assert record["stages"][1]["init_from"] == str(run / "one")  # the second starts from the first
    assert all(s["wall_s"] > 0 for s in record["stages"]) and record["stages"][1]["seed"] == 2
    # stage two started from stage one's model: it took over its input statistics (frozen after
    # stage one's warm-up) instead of gathering its own
    one, _ = ckpt.read_checkpoint(run / "one")
    two, _ = ckpt.read_checkpoint(run / "two")
    stats = [k for k in one if k.startswith(("node_normalizer.", "edge_normalizer."))]
    assert stats and all(torch.equal(one[k], two[k]) for k in stats)
    # shipped: the last stage's model with its training record and the recipe's
    model, info = ckpt.load_model(tmp_path / "model")
    assert model.config.solver.value == "two_level"
    shipped, _ = ckpt.read_checkpoint(tmp_path / "model")
    last, _ = ckpt.read_checkpoint(run / "two")
    assert all(torch.equal(shipped[k], last[k]) for k in last)
    assert json.loads((tmp_path / "record" / "recipe.json").read_text())["stages"][1]["name"] == "two"
    for name in ("one", "two"):  # every stage's record
        assert json.loads((tmp_path / "record" / name / "record.json").read_text())["checkpoint"].startswith("step-")
        assert (tmp_path / "record" / name / "loss_curve.png").is_file()
    # a second call without --resume refuses; with it, finished stages are skipped
    with pytest.raises(ConfigError, match="--resume"):
        run_recipe(recipe, run, source=source, command="c", log=lambda _: None)
    logs = []
    again = run_recipe(recipe, run, source=source, command="c", resume=True, log=logs.append)
    assert not any(line.startswith("[recipe] stage") for line in logs)
    assert [s["wall_s"] for s in again["stages"]] == [s["wall_s"] for s in record["stages"]]


def test_an_interrupted_stage_resumes(recipe, tmp_path):
    run = tmp_path / "run"
    run_recipe(recipe, run, source=source, command="c", log=lambda _: None)
    (run / "two" / "latest").write_text("step-00000002\n")  # as if killed after step 2 of 3
    logs = []
    run_recipe(recipe, run, source=source, command="c", resume=True, log=logs.append)
    assert logs[0].startswith("[recipe] stage two") and "steps 2..3" in logs[0]
    assert ckpt.latest_checkpoint(run / "two").name == "step-00000003"


@pytest.mark.parametrize("text, pattern", [
    ("stages: []", "at least one stage"),
    ("stages: [{name: a}]", "`name`, `config` and optionally `until`"),
    ("stages: [{name: ../a, config: c.yaml}]", "plain directory name"),
    ("stages: [{name: a, config: c.yaml}]\nship: {model_out: m}", "model_out and record_out"),
    ("stages: [{name: a, config: c.yaml}]\nship: {model_out: m, record_out: r, variant: gnn_only}", "ship.variant"),
    ("stages: [{name: a, config: c.yaml}]\nship: {model_out: m, record_out: r, passes: 0}", "ship.passes"),
    ("stages: [{name: a, config: c.yaml}]\nship: {model_out: m, record_out: r, passes: two}", "ship.passes"),
    ("stages: [{name: a, config: c.yaml}]\nship: {model_out: m, record_out: r, eval_move_gain: 0}",
     "ship.eval_move_gain"),
    ("steps: 3", "a list `stages`"),
])
def test_a_bad_recipe_is_named(tmp_path, text, pattern):
    path = tmp_path / "r.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError, match=pattern):
        load_recipe(path)


def test_the_shipped_recipe_names_existing_configs():
    recipe = load_recipe("configs/recipes/shipped.yaml")
    assert [s.config.is_file() for s in recipe.stages] == [True] * len(recipe.stages)
    assert str(recipe.model_out) == "src/physdrape/assets/models/cpu_default"


def test_until_stops_a_stage_on_its_full_schedule(tmp_path):
    first = _config(tmp_path / "a.yaml", solver="explicit", steps=4, seed=1)
    second = _config(tmp_path / "b.yaml", solver="explicit", steps=2, seed=2)
    path = tmp_path / "recipe.yaml"
    path.write_text(yaml.safe_dump({"stages": [{"name": "one", "config": str(first), "until": 2},
                                               {"name": "two", "config": str(second)}]}))
    record = run_recipe(path, tmp_path / "run", source=source, command="c", log=lambda _: None)
    assert ckpt.latest_checkpoint(tmp_path / "run" / "one").name == "step-00000002"
    assert (record["stages"][0]["steps"], record["stages"][0]["schedule_steps"]) == (2, 4)
    assert all(s["wall_s"] > 0 for s in record["stages"])
    # the learning rate at the stop is that of the 4-step schedule, not of a 2-step one
    lines = [json.loads(line) for line in (tmp_path / "run" / "one" / "metrics.jsonl").read_text().splitlines()]
    assert lines[-1]["step"] == 2 and lines[-1]["lr"] == pytest.approx(1e-3 * 0.1 ** (2 / 4))


def test_a_network_trained_alone_ships_to_drape_through_the_solver(tmp_path):
    """ship.variant: the last stage trained GNN-only, shipped to run as the full model; its record
    keeps the variant it was trained as, and an explicit variant still wins when loading."""
    only = _config(tmp_path / "a.yaml", solver="two_level", steps=2, seed=1)
    text = yaml.safe_load(only.read_text())
    text["model"]["variant"] = "gnn"
    only.write_text(yaml.safe_dump(text))
    path = tmp_path / "recipe.yaml"
    path.write_text(yaml.safe_dump({"stages": [{"name": "gnn", "config": str(only)}],
                                    "ship": {"model_out": str(tmp_path / "model"), "record_out": str(tmp_path / "record"),
                                             "variant": "full"}}))
    run_recipe(path, tmp_path / "run", source=source, command="c", log=lambda _: None)
    model, info = ckpt.load_model(tmp_path / "model")
    assert info["variant"] == "full" and model.config.variant.uses_solver and model.config.variant.uses_handler
    assert ckpt.load_model(tmp_path / "run" / "gnn")[1]["variant"] == "gnn"  # the run itself: as trained
    assert ckpt.load_model(tmp_path / "model", variant=Variant.GNN_ONLY)[1]["variant"] == "gnn"
    _, config = ckpt.read_checkpoint(tmp_path / "model")
    assert config["train"]["model"]["variant"] == "gnn" and config["variant"] == "full"
    config["variant"] = "everything"
    (tmp_path / "model" / "config.json").write_text(json.dumps(config))
    with pytest.raises(ckpt.CheckpointError, match="variant 'everything'"):
        ckpt.load_model(tmp_path / "model")


def test_a_network_trained_as_one_pass_ships_to_make_two(tmp_path):
    """ship.passes: the exported model's network makes that many passes, its record keeps the
    passes it was trained with, and an explicit number still wins when loading; a bad number in
    config.json is named."""
    one = _config(tmp_path / "a.yaml", solver="two_level", steps=2, seed=1)
    path = tmp_path / "recipe.yaml"
    ship = {"model_out": str(tmp_path / "model"), "record_out": str(tmp_path / "record"), "passes": 2}
    path.write_text(yaml.safe_dump({"stages": [{"name": "one", "config": str(one)}], "ship": ship}))
    run_recipe(path, tmp_path / "run", source=source, command="c", log=lambda _: None)
    model, info = ckpt.load_model(tmp_path / "model")
    assert info["passes"] == 2 and model.config.passes == 2
    assert ckpt.load_model(tmp_path / "run" / "one")[1]["passes"] == 1  # the run itself: as trained
    assert ckpt.load_model(tmp_path / "model", passes=3)[0].config.passes == 3
    _, config = ckpt.read_checkpoint(tmp_path / "model")
    assert config["train"]["model"]["passes"] == 1 and config["passes"] == 2
    config["passes"] = 0
    (tmp_path / "model" / "config.json").write_text(json.dumps(config))
    with pytest.raises(ckpt.CheckpointError, match="passes 0"):
        ckpt.load_model(tmp_path / "model")


def test_a_network_ships_with_its_solver_start_gain(tmp_path):
    """ship.eval_move_gain: the exported model's solver starts from X_init + g Δx, the run itself
    keeps g = 1; a bad gain in config.json is named."""
    one = _config(tmp_path / "a.yaml", solver="two_level", steps=2, seed=1)
    path = tmp_path / "recipe.yaml"
    ship = {"model_out": str(tmp_path / "model"), "record_out": str(tmp_path / "record"), "eval_move_gain": 1.3}
    path.write_text(yaml.safe_dump({"stages": [{"name": "one", "config": str(one)}], "ship": ship}))
    run_recipe(path, tmp_path / "run", source=source, command="c", log=lambda _: None)
    assert ckpt.load_model(tmp_path / "model")[0].config.eval_move_gain == 1.3
    assert ckpt.load_model(tmp_path / "run" / "one")[0].config.eval_move_gain == 1.0
    _, config = ckpt.read_checkpoint(tmp_path / "model")
    config["eval_move_gain"] = -1
    (tmp_path / "model" / "config.json").write_text(json.dumps(config))
    with pytest.raises(ckpt.CheckpointError, match="eval_move_gain -1"):
        ckpt.load_model(tmp_path / "model")

"""A training recipe: run configs as consecutive stages into one run directory, then ship.

A recipe is a YAML file::

    stages:                      # run in order; stage k > 0 starts from stage k-1's weights
      - {name: gnn, config: configs/global/gnn_energy.yaml, until: 1200}
      - {name: full, config: configs/global/full_teacher.yaml}
    ship:                        # optional: where the last stage's model and record go
      model_out: src/physdrape/assets/models/cpu_default
      record_out: docs/training/shipped
      variant: full              # optional: the variant the shipped model runs as (default: as trained)
      passes: 2                  # optional: the network passes it makes (default: as trained)
      eval_move_gain: 1.3        # optional: its solver's start X_init + g Δx (default: as trained)

`physdrape train --recipe FILE --run-dir DIR [--resume]` trains stage k into DIR/<name>, with
``optim.init_from`` set to DIR/<previous name> (whatever the stage's config says), skips stages
that already reached their steps, and resumes an interrupted stage from its latest checkpoint. A
stage's optional ``until`` stops it at that step, with the learning-rate schedule of its config's
full ``optim.steps`` (a run stopped there by hand is the same run). DIR/recipe.json records the
command, and per stage its config, seed, steps and the wall time spent in it (summed over its
resumed segments, as its metrics.jsonl logged them). With ``ship``, the last stage's model is exported and
every stage's training record written into record_out/<stage name> (`physdrape.train.ship`), with
the recipe's record beside them; ``variant`` ships it to run as that variant (`export_model`): a
network trained alone (GNN-only) shipped to drape through the solver and the handler; ``passes``
ships its network to make that many passes (`ModelConfig.passes`), ``eval_move_gain`` its solver
to start from the network's move extrapolated by that gain (`ModelConfig.eval_move_gain`).
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

from physdrape.atomic import write_text
from physdrape.checkpoint import export_model, latest_checkpoint
from physdrape.config_io import ConfigError, load_config, read_yaml
from physdrape.model import Variant
from physdrape.train.trainer import SampleSource, TrainConfig, Trainer


@dataclass(frozen=True)
class Stage:
    """One stage: a name (its run sub-directory), the YAML run config it trains and the step it
    stops at (None: the config's optim.steps)."""

    name: str
    config: Path
    until: int | None = None


@dataclass(frozen=True)
class Recipe:
    """Stages in order and, optionally, where to ship the last one (model dir, record dir), the
    variant it runs as there and its network's passes (None: as trained)."""

    stages: tuple[Stage, ...]
    model_out: Path | None = None
    record_out: Path | None = None
    variant: str | None = None
    passes: int | None = None
    eval_move_gain: float | None = None


def load_recipe(path: str | Path) -> Recipe:
    """Read a recipe strictly; config paths are relative to the current directory (the checkout)."""
    path = Path(path)
    data = read_yaml(path, what="recipe")
    if not isinstance(data, dict) or set(data) - {"stages", "ship"} or not isinstance(data.get("stages"), list):
        raise ConfigError(f"{path}: a recipe is a mapping with a list `stages` (each {{name, config}}) and an "
                          "optional `ship` {model_out, record_out}")
    stages = []
    for k, item in enumerate(data["stages"]):
        if not isinstance(item, dict) or not {"name", "config"} <= set(item) <= {"name", "config", "until"}:
            raise ConfigError(f"{path}: stage {k} must have `name`, `config` and optionally `until`, got {item!r}")
        until = item.get("until")
        if until is not None and (not isinstance(until, int) or until < 1):
            raise ConfigError(f"{path}: stage {k}'s `until` must be a step ≥ 1, got {until!r}")
        name = str(item["name"])
        if not name or "/" in name or name.startswith("."):
            raise ConfigError(f"{path}: stage name {name!r} must be a plain directory name")
        stages.append(Stage(name, Path(item["config"]), until))
    if not stages or len({s.name for s in stages}) != len(stages):
        raise ConfigError(f"{path}: give at least one stage, with distinct names")
    ship = data.get("ship") or {}
    allowed = {"model_out", "record_out", "variant", "passes", "eval_move_gain"}
    if set(ship) - allowed or (ship and not {"model_out", "record_out"} <= set(ship)):
        raise ConfigError(f"{path}: `ship` takes model_out and record_out, and optionally variant, passes and "
                          f"eval_move_gain")
    variant = ship.get("variant")
    if variant is not None and variant not in [v.value for v in Variant]:
        raise ConfigError(f"{path}: ship.variant must be one of {[v.value for v in Variant]}, got {variant!r}")
    passes = ship.get("passes")
    if passes is not None and (not isinstance(passes, int) or isinstance(passes, bool) or passes < 1):
        raise ConfigError(f"{path}: ship.passes must be an integer ≥ 1, got {passes!r}")
    gain = ship.get("eval_move_gain")
    if gain is not None and (isinstance(gain, bool) or not isinstance(gain, (int, float)) or not gain > 0):
        raise ConfigError(f"{path}: ship.eval_move_gain must be a number > 0, got {gain!r}")
    return Recipe(tuple(stages), Path(ship["model_out"]) if ship else None,
                  Path(ship["record_out"]) if ship else None, variant, passes,
                  None if gain is None else float(gain))


def stage_configs(recipe: Recipe, run_dir: Path) -> list[TrainConfig]:
    """Each stage's config, chained: stage k > 0 starts from stage k-1's run directory."""
    configs = []
    for k, stage in enumerate(recipe.stages):
        config = load_config(TrainConfig, stage.config)
        if k > 0:
            previous = run_dir / recipe.stages[k - 1].name
            config = replace(config, optim=replace(config.optim, init_from=str(previous)))
        configs.append(config)
    return configs


def _finished_step(stage_dir: Path) -> int:
    latest = latest_checkpoint(stage_dir) if stage_dir.is_dir() else None
    return int(latest.name.split("-")[-1]) if latest is not None else 0


def logged_wall_s(stage_dir: Path, *, upto: int) -> float:
    """Wall seconds a stage's training took up to step `upto`, from its metrics.jsonl: the sum over
    its segments (each run or resumed run restarts wall_s) of the last logged wall_s."""
    path = stage_dir / "metrics.jsonl"
    if not path.is_file():
        return 0.0
    total = last = 0.0
    for line in path.read_text().splitlines():
        if not line.strip():
            continue
        entry = json.loads(line)
        if entry["step"] > upto:
            break
        if entry["wall_s"] < last:  # a new segment
            total += last
        last = entry["wall_s"]
    return total + last


def run_recipe(recipe_path: str | Path, run_dir: str | Path, *, source: Callable[[TrainConfig], SampleSource],
               command: str, resume: bool = False, log=print, device: str = "cpu",
               compile_network: bool = False) -> dict:
    """Train the recipe's stages in order into run_dir (see the module docstring) on `device`
    (with `compile_network`, each stage's network compiled: `Trainer`); returns the record.

    source: builds the sample source of a stage from its config (the CLI: `DrapeSource(config.data, model=config.model)`).
    """
    recipe = load_recipe(recipe_path)
    run_dir = Path(run_dir)
    configs = stage_configs(recipe, run_dir)  # every config is checked before any training
    record_path = run_dir / "recipe.json"
    if not resume and any((run_dir / s.name).exists() for s in recipe.stages):
        raise ConfigError(f"{run_dir} already holds stages of a run: pass --resume to continue it, or choose "
                          "another --run-dir")
    record = {"command": command, "recipe": str(recipe_path), "stages": []}
    for stage, config in zip(recipe.stages, configs):
        stage_dir = run_dir / stage.name
        done = _finished_step(stage_dir)
        stop = min(stage.until or config.optim.steps, config.optim.steps)
        if done < stop:
            log(f"[recipe] stage {stage.name}: {stage.config}, steps {done}..{stop}")
            Trainer(config, source(config), stage_dir, device=device,
                    compile_network=compile_network).run(resume=done > 0, until=stop)
        record["stages"].append({"name": stage.name, "config": str(stage.config), "seed": config.optim.seed,
                                 "steps": stop, "schedule_steps": config.optim.steps,
                                 "init_from": config.optim.init_from, "wall_s": logged_wall_s(stage_dir, upto=stop)})
        write_text(record_path, json.dumps(record, indent=2) + "\n")
    record["wall_s"] = sum(s["wall_s"] for s in record["stages"])
    write_text(record_path, json.dumps(record, indent=2) + "\n")
    if recipe.model_out is not None:
        from physdrape.train.ship import write_record

        export_model(latest_checkpoint(run_dir / recipe.stages[-1].name), recipe.model_out, variant=recipe.variant,
                     passes=recipe.passes, eval_move_gain=recipe.eval_move_gain)
        for stage in recipe.stages:
            write_record(run_dir / stage.name, recipe.record_out / stage.name, command=command)
        write_text(recipe.record_out / "recipe.json", json.dumps(record, indent=2) + "\n")
        log(f"[recipe] shipped {recipe.model_out} and its record {recipe.record_out}")
    return record

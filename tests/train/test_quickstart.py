"""configs/quickstart.yaml: it loads, trains on the real pipeline and lowers the loss; its data
generates only the garments it reads."""

from dataclasses import replace
from pathlib import Path

import pytest

from physdrape.config_io import load_config
from physdrape.garments.split import read_manifest
from physdrape.train.data import DataConfig, DrapeSource, load_templates
from physdrape.train.trainer import TrainConfig, Trainer

QUICKSTART = Path(__file__).resolve().parents[2] / "configs" / "quickstart.yaml"

pytestmark = pytest.mark.anny


def test_quickstart_config_lowers_the_loss_on_the_real_pipeline(tmp_path, tiny_split, anny_body, capsys):
    config = load_config(TrainConfig, QUICKSTART)
    assert config.model.variant.value == "gnn" and config.model.levels > 0 and config.data.max_garments == 6
    assert config.data.instances and config.optim.validate_every
    # The quickstart's model, loss and optimiser on real cached instances (the tiny split's 2
    # training garments, one held out; Anny bodies), 12 steps on one batch, as in test_training.
    data = replace(config.data, split_dir=tiny_split, max_garments=2, validation_garments=1, instance_count=2,
                   validation_count=1, teacher_steps=10, instances=str(tmp_path / "instances"))
    config = replace(config, data=data, optim=replace(config.optim, steps=12, log_every=1, checkpoint_every=12,
                                                     validate_every=12))
    source = DrapeSource(config.data, model=config.model, body=anny_body)
    assert len(source.templates) == 2 and len(source.pool) == 8
    fixed = source.make_batch([11, 12])
    source.make_batch = lambda seeds: fixed
    history = Trainer(config, source, tmp_path / "run", progress=True, tensorboard=False).run()
    # the held-out curve is printed under the progress bar at each validation; the bar itself,
    # into a stream that is not a terminal, is not redrawn at every one of the 12 steps
    err = capsys.readouterr().err
    assert err.count("train:") <= 6, err
    printed = [line for line in err.splitlines() if "held-out energy gap" in line]
    assert [line.split(":")[0] for line in printed] == ["step 0", "step 12"], printed
    assert "gnn 1.000" in printed[0]  # the zero-initialised network leaves X_init's whole gap
    losses = [r["loss"] for r in history]
    # the loss holds E_grav, an offset of the garment's height: a fall of 1 % of it is a fall of
    # several percent of the energy above equilibrium
    assert all(b <= a for a, b in zip(losses, losses[1:])) and losses[-1] < 0.99 * losses[0], losses
    assert len((tmp_path / "run" / "metrics.jsonl").read_text().splitlines()) == 12
    assert len((tmp_path / "run" / "validation.jsonl").read_text().splitlines()) == 2  # steps 0 and 12


def test_training_data_generates_only_the_garments_it_reads(tmp_path):
    split = tmp_path / "split"
    templates = load_templates(DataConfig(split_dir=str(split), subset="test", max_garments=1))
    assert [t.name for t in templates] == ["0000_tshirt"]
    assert sorted(str(p.relative_to(split)) for p in split.rglob("*.ply")) == ["test/0000_tshirt.ply"]
    manifest = read_manifest(split)
    assert (manifest["num_train"], manifest["num_test"], len(manifest["garments"])) == (600, 30, 1)

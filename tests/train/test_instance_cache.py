"""Cached training instances with teacher drapes, the teacher loss and the held-out curve."""

import json
from dataclasses import replace

import pytest
import torch

from physdrape.body.skinning_transfer import SkinningTransfer
from physdrape.model import ModelConfig
from physdrape.physics.energy import total_energy
from physdrape.pipeline import PosedBodies
from physdrape.train.curves import plot_validation
from physdrape.train.data import DataConfig, DrapeSource
from physdrape.train.instances import X_INIT_SETTINGS, InstanceCacheError
from physdrape.train.loss import LossConfig, drape_loss, teacher_distance
from physdrape.train.trainer import OptimConfig, TrainConfig, Trainer

pytestmark = pytest.mark.anny

SMALL = ModelConfig(latent=8, blocks=3, levels=1, zero_init_output=True)


def _data(tiny_split, cache) -> DataConfig:
    return DataConfig(split_dir=tiny_split, body_pool_size=2, instances=str(cache), instance_count=2,
                      validation_count=1, validation_garments=1, teacher_steps=4)


def test_cache_holds_teacher_drapes_that_lower_the_energy_and_grows_without_changing(tmp_path, tiny_split, anny_body):
    data = _data(tiny_split, tmp_path / "cache")
    source = DrapeSource(data, model=SMALL, body=anny_body)
    manifest = json.loads((tmp_path / "cache" / "manifest.json").read_text())
    assert [len(manifest["parts"][p]) for p in ("train", "val")] == [2, 1]
    # the training part draws from garment 0 only, the held-out garment 1 is validation's
    assert {r["garment"] for r in manifest["parts"]["train"]} == {0}
    assert {r["garment"] for r in manifest["parts"]["val"]} == {1}
    sample = source.make_batch([3, 4])
    assert sample.teacher.shape == sample.drape.x_init.shape
    d = sample.drape
    contact = dict(contact_stiffness=SMALL.contact_stiffness, margin=SMALL.margin)
    start = total_energy(d.x_init, d.cloth, d.bodies, d.body_index, **contact)
    assert (total_energy(sample.teacher, d.cloth, d.bodies, d.body_index, **contact) < start).all()
    # every sample is draped on the pool's surface, built once: the same bodies as a surface of
    # the sample's own bodies, whose energies the teacher lowered
    pool_surface = source.posed_pool().surface(source.dtype, "cpu")
    assert d.bodies is pool_surface and source.make_batch([5]).drape.bodies is pool_surface
    own = PosedBodies(source.pool.state(d.body_index.unique().tolist())).surface(source.dtype, "cpu")
    own_index = torch.searchsorted(d.body_index.unique(), d.body_index)
    torch.testing.assert_close(total_energy(d.x_init, d.cloth, own, own_index, **contact), start, rtol=0, atol=0)
    first = (tmp_path / "cache" / "train" / "000000.safetensors").read_bytes()
    DrapeSource(replace(data, instance_count=3), model=SMALL, body=anny_body)
    assert (tmp_path / "cache" / "train" / "000000.safetensors").read_bytes() == first
    assert (tmp_path / "cache" / "train" / "000002.safetensors").is_file()
    with pytest.raises(InstanceCacheError, match="other settings"):
        DrapeSource(replace(data, teacher_steps=5), model=SMALL, body=anny_body)
    # X_init's limiter settings are part of what the cache was made with: a manifest written
    # before they were recorded (X_init without the compression bound) is refused
    assert manifest["x_init"] == X_INIT_SETTINGS
    assert X_INIT_SETTINGS["min_stretch"] == SkinningTransfer.min_stretch
    path = tmp_path / "cache" / "manifest.json"
    kept = path.read_text()
    path.write_text(json.dumps({k: v for k, v in json.loads(kept).items() if k != "x_init"}))
    with pytest.raises(InstanceCacheError, match="other settings"):
        DrapeSource(data, model=SMALL, body=anny_body)
    path.write_text(kept)
    other = source.templates[::-1]  # a split whose garment 0 is another garment
    with pytest.raises(InstanceCacheError, match="another garment split"):
        DrapeSource(data, model=SMALL, body=anny_body, templates=other)


def test_teacher_term_pulls_toward_the_teacher(tmp_path, tiny_split, anny_body):
    sample = DrapeSource(_data(tiny_split, tmp_path / "cache"), model=SMALL, body=anny_body).make_batch([1])
    d = sample.drape
    contact = dict(contact_stiffness=SMALL.contact_stiffness, margin=SMALL.margin)
    assert float(teacher_distance(sample.teacher, sample.teacher, d.cloth).max()) == 0.0
    x = d.x_init.clone().requires_grad_(True)
    loss, terms = drape_loss(x, d.cloth, d.bodies, d.body_index, LossConfig(teacher_weight=1e3), teacher=sample.teacher,
                             **contact)
    plain, _ = drape_loss(x, d.cloth, d.bodies, d.body_index, LossConfig(), **contact)
    distance = teacher_distance(x, sample.teacher, d.cloth)
    torch.testing.assert_close(loss, plain + 1e3 * distance.mean())
    coarse, _ = drape_loss(x, d.cloth, d.bodies, d.body_index, LossConfig(teacher_weight=1e3, teacher_levels=2),
                           teacher=sample.teacher, **contact)
    torch.testing.assert_close(coarse, plain + 1e3 * teacher_distance(x, sample.teacher, d.cloth, levels=2).mean())
    # its gradient is 2 m_i (x_i − t_i) / Σm per garment
    (grad,) = torch.autograd.grad(distance.sum(), x)
    mass = d.cloth.mass[:, None] / d.cloth.sum_per_garment(d.cloth.mass, d.cloth.vert_garment)[d.cloth.vert_garment, None]
    torch.testing.assert_close(grad, 2 * mass * (d.x_init - sample.teacher))
    assert terms["teacher_rms"] > 0
    with pytest.raises(ValueError, match="data.instances"):
        drape_loss(x, d.cloth, d.bodies, d.body_index, LossConfig(teacher_weight=1.0), **contact)


def test_training_on_the_cache_lowers_the_loss_and_logs_the_held_out_curve(tmp_path, tiny_split, anny_body):
    config = TrainConfig(model=replace(SMALL, variant="gnn"), loss=LossConfig(teacher_weight=1e3),
                         optim=OptimConfig(steps=16, batch_size=1, lr=3e-3, checkpoint_every=8, log_every=1,
                                           validate_every=8),
                         data=_data(tiny_split, tmp_path / "cache"))
    source = DrapeSource(config.data, model=config.model, body=anny_body)
    fixed = source.make_batch([5])
    source.make_batch = lambda seeds: fixed
    history = Trainer(config, source, tmp_path / "run", progress=False, tensorboard=False).run()
    losses = [r["loss"] for r in history]
    # X_init already has little compression or stretch left (its strain limiter bounds both):
    # 16 steps on one instance take a few percent off, every step lower than the one before
    assert sum(losses[-3:]) < 0.98 * sum(losses[:3]), losses
    assert all(b < a for a, b in zip(losses, losses[1:])), losses
    rows = [json.loads(line) for line in (tmp_path / "run" / "validation.jsonl").read_text().splitlines()]
    assert [r["step"] for r in rows] == [0, 8, 16]
    for key in ("gnn", "t3", "t15", "solver_t3", "solver_t15"):
        assert rows[-1][f"{key}/energy_ratio"] > 0 and rows[-1][f"{key}/b2g_percent"] >= 0
    # before training the zero-initialised network is X_init: the whole gap is left
    assert rows[0]["gnn/energy_gap"] == pytest.approx(1.0, abs=1e-6)
    assert rows[0]["solver_t15/energy_gap"] < 1.0
    plot_validation(rows, tmp_path / "validation.png")
    assert (tmp_path / "validation.png").stat().st_size > 10_000


def test_a_build_in_two_processes_writes_the_same_instances(tmp_path, tiny_split, anny_body):
    from physdrape.train.data import load_templates
    from physdrape.train.instances import InstanceCache, part_pool

    data = _data(tiny_split, tmp_path / "cache")
    templates = load_templates(data)
    pools = {p: part_pool(anny_body, data, p) for p in ("train", "val")}
    counts = {"train": 2, "val": 1}
    for workers in (1, 2):
        InstanceCache(tmp_path / f"w{workers}", data, SMALL).build(templates, anny_body, pools, counts, workers=workers)
    one, two = (json.loads((tmp_path / f"w{w}" / "manifest.json").read_text()) for w in (1, 2))
    assert one == two and [len(one["parts"][p]) for p in ("train", "val")] == [2, 1]
    for name in ("train/000000", "train/000001", "val/000000"):
        a, b = ((tmp_path / f"w{w}" / f"{name}.safetensors").read_bytes() for w in (1, 2))
        assert a == b, name

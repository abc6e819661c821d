"""The model, solver, collision handler and body queries on every available device, and a CPU
check that catches a tensor made without `device=` (it would land on the default device)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import torch
import trimesh
from device_params import DEVICES
from drape_cases import make_input, tube

from physdrape.geometry.garment import GarmentBatch
from physdrape.geometry.proximity import BodySurface
from physdrape.model import DrapeInput, ModelConfig, PhysDrape
from physdrape.physics import Cloth, Material
from physdrape.physics.metrics import drape_metrics
from physdrape.train.loss import LossConfig, drape_loss

#: Every device-dependent path: hierarchical GNN, two-level solver with its coarse space and
#: contact, the handler's centroid pass; and the explicit solver.
CONFIGS = {
    "two_level": ModelConfig(latent=8, blocks=3, levels=2, solver="two_level", eta=1.0, gamma=0.98, max_step=0.01,
                             requery_every=2, centroid_margin=5e-3),
    "explicit": ModelConfig(latent=8, blocks=2, solver="explicit", eta=1e-3, gamma=0.9, max_step=5e-3),
}


def _tensors(value, seen=None):
    """Every tensor reachable through dataclass fields, tuples and lists."""
    if isinstance(value, torch.Tensor):
        yield value
    elif dataclasses.is_dataclass(value) and not isinstance(value, type):
        for f in dataclasses.fields(value):
            yield from _tensors(getattr(value, f.name))
    elif isinstance(value, (tuple, list)):
        for item in value:
            yield from _tensors(item)


def _model(name: str) -> PhysDrape:
    torch.manual_seed(0)
    return PhysDrape(CONFIGS[name])


def _sphere(radii) -> tuple[torch.Tensor, torch.Tensor]:
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    verts = torch.from_numpy(np.asarray(sphere.vertices, dtype=np.float32))
    return torch.stack([verts * r for r in radii]), torch.from_numpy(np.asarray(sphere.faces, dtype=np.int64))


@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_nothing_is_made_on_the_default_device(name):
    """With the default device set to "meta", a torch factory call without `device=` makes a meta
    tensor, which fails as soon as it meets the CPU tensors: building a batch, a forward pass
    with the solver and handler, the loss, its backward and the metrics must not make one."""
    model = _model(name).train()
    garments = [tube(6, 16, 0.14, name="a"), tube(5, 13, 0.17, name="b")]
    verts, faces = _sphere([0.15, 0.16])
    with torch.device("meta"):
        batch = GarmentBatch.pack(garments)
        cloth = Cloth.build(batch, [Material(), Material(density=0.3)])
        inp = DrapeInput(batch, cloth, batch.rest.clone(), BodySurface(verts, faces), batch.vert_garment)
        model.accumulate_statistics(inp)
        out = model(inp, steps=4, keep_trace=True)
        loss, _ = drape_loss(out.x, cloth, inp.bodies, inp.body_index, LossConfig(per_garment_scale="initial"),
                             inp.x_init, contact_stiffness=model.config.contact_stiffness, margin=model.config.margin)
        loss.backward()
        metrics = drape_metrics(out.x.detach(), batch, inp.bodies, inp.body_index, cloth=cloth)
        physics = model.physics_only(inp, steps=2)
    assert out.x.device.type == "cpu" and bool(torch.isfinite(out.x).all()) and bool(torch.isfinite(loss))
    assert all(p.grad is not None and p.grad.device.type == "cpu" for p in model.parameters() if p.requires_grad)
    assert all(np.isfinite(v).all() for v in metrics.as_dict().values())
    assert physics.x.device.type == "cpu"


def test_batches_move_every_tensor():
    """`to(device=...)` of a garment batch and a cloth leaves no tensor behind (meta: no data moves)."""
    batch = GarmentBatch.pack([tube(6, 16, 0.14), tube(5, 13, 0.17)])
    cloth = Cloth.build(batch, Material())
    for moved in (batch.to(device="meta"), cloth.to(device="meta"), batch.to(torch.float64, device="meta")):
        devices = {t.device.type for t in _tensors(moved)}
        assert devices == {"meta"}, devices
    assert {t.dtype for t in _tensors(batch.to(torch.float64)) if t.is_floating_point()} == {torch.float64}


@pytest.mark.parametrize("device", DEVICES)
@pytest.mark.parametrize("name", sorted(CONFIGS))
def test_drape_on_device(device, name):
    """A forward and backward pass on `device` stays there and agrees with the CPU."""
    inp = make_input([tube(6, 16, 0.14, name="a"), tube(5, 13, 0.17, name="b")], [0.15, 0.16])
    reference = _model(name).train()
    reference.accumulate_statistics(inp)
    model = _model(name).train().to(device)
    model.load_state_dict(reference.state_dict())
    moved = inp.to(device)
    assert {t.device.type for t in _tensors(moved.garments)} | {t.device.type for t in _tensors(moved.cloth)} \
        == {device}
    assert moved.bodies.device.type == device and moved.x_init.device.type == device
    out = model(moved, steps=4, keep_trace=True)
    expected = reference(inp, steps=4, keep_trace=True)
    assert all(x.device.type == device for x in (out.x, out.x_gnn, out.f_hat, *out.trace))
    torch.testing.assert_close(out.x.cpu(), expected.x, atol=1e-4, rtol=0)
    contact = dict(contact_stiffness=model.config.contact_stiffness, margin=model.config.margin)
    loss, _ = drape_loss(out.x, moved.cloth, moved.bodies, moved.body_index, LossConfig(), **contact)
    loss.backward()
    assert all(p.grad.device.type == device for p in model.parameters() if p.grad is not None)
    metrics = drape_metrics(out.x.detach(), moved.garments, moved.bodies, moved.body_index, cloth=moved.cloth)
    assert all(np.isfinite(v).all() for v in metrics.as_dict().values())

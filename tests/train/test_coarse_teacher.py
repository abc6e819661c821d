"""The teacher term on the coarse patches (`LossConfig.teacher_levels`): it measures only the
smooth part of the drape's difference from the teacher."""

import pytest
import torch

from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet, open_cylinder
from physdrape.physics import Cloth
from physdrape.train.loss import LossConfig, teacher_distance


def _cloth():
    sheet = Garment.from_mesh(*grid_sheet(16, 12, width=0.4, height=0.3), name="sheet", dtype=torch.float64)
    tube = Garment.from_mesh(*open_cylinder(8, 18, radius=0.12, length=0.3), name="tube", dtype=torch.float64)
    batch = GarmentBatch.pack([sheet, tube])
    return batch.rest, Cloth.build(batch)


def test_a_smooth_difference_counts_whole_and_vertex_noise_mostly_not():
    teacher, cloth = _cloth()
    gen = torch.Generator().manual_seed(0)
    shift = torch.tensor([0.01, -0.02, 0.005], dtype=torch.float64)
    bend = 0.02 * torch.sin(3 * teacher[:, :1]) * torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
    for smooth, rtol in ((shift.expand_as(teacher), 1e-9), (bend, 0.1)):  # a shift exactly, a slow wave nearly
        full = teacher_distance(teacher + smooth, teacher, cloth)
        coarse = teacher_distance(teacher + smooth, teacher, cloth, levels=2)
        torch.testing.assert_close(coarse, full, rtol=rtol, atol=0)
    noise = 1e-3 * torch.randn(teacher.shape, generator=gen, dtype=torch.float64)
    full = teacher_distance(teacher + noise, teacher, cloth)
    coarse = teacher_distance(teacher + noise, teacher, cloth, levels=2)
    assert bool((coarse < 0.2 * full).all()), (coarse, full)
    x = (teacher + noise + shift).requires_grad_(True)
    (grad,) = torch.autograd.grad(teacher_distance(x, teacher, cloth, levels=2).sum(), x)
    (along,) = torch.autograd.grad(teacher_distance(x, teacher, cloth).sum(), x)
    assert float(grad.norm()) < float(along.norm())  # the pull acts on the smooth part only


def test_teacher_levels_must_be_a_level():
    with pytest.raises(ValueError, match="teacher_levels"):
        LossConfig(teacher_levels=-1)

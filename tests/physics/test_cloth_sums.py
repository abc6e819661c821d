"""Cloth.sum_vertex_field: per-garment sums of a per-vertex field, against the scatter of row sums."""

from dataclasses import replace

import torch

from physdrape.geometry.garment import GarmentBatch
from physdrape.physics.cloth import Cloth


def _scattered(cloth: Cloth, values: torch.Tensor) -> torch.Tensor:
    return cloth.sum_per_garment(values.reshape(values.shape[0], -1).sum(-1), cloth.vert_garment)


def test_each_garment_summed_on_its_own(sheet, tube):
    cloth = Cloth.build(GarmentBatch.pack([sheet, tube, sheet]))
    gen = torch.Generator().manual_seed(0)
    values = torch.randn(cloth.vert_garment.shape[0], 3, dtype=torch.float64, generator=gen)
    torch.testing.assert_close(cloth.sum_vertex_field(values), _scattered(cloth, values), rtol=1e-12, atol=1e-12)
    # a garment's sum is its sum alone: the same in a batch as by itself
    alone = Cloth.build(GarmentBatch.pack([tube]))
    rows = slice(sheet.num_verts, sheet.num_verts + tube.num_verts)
    assert cloth.sum_vertex_field(values)[1] == alone.sum_vertex_field(values[rows])[0]


def test_rows_not_grouped_by_garment_are_scattered(sheet, tube):
    cloth = Cloth.build(GarmentBatch.pack([sheet, tube]))
    order = torch.randperm(cloth.vert_garment.shape[0], generator=torch.Generator().manual_seed(1))
    shuffled = replace(cloth, vert_garment=cloth.vert_garment[order])
    values = torch.randn(len(order), 3, dtype=torch.float64, generator=torch.Generator().manual_seed(2))
    torch.testing.assert_close(shuffled.sum_vertex_field(values), _scattered(shuffled, values), rtol=1e-12, atol=1e-12)


def test_a_garment_without_vertices_sums_to_zero(sheet):
    one = Cloth.build(GarmentBatch.pack([sheet]))
    values = torch.ones(sheet.num_verts, 3, dtype=torch.float64)
    assert one.sum_vertex_field(values).tolist() == [3.0 * sheet.num_verts]
    # the same owner tensor in a cloth of two garments, the second without vertices
    assert replace(one, num_garments=2).sum_vertex_field(values).tolist() == [3.0 * sheet.num_verts, 0.0]

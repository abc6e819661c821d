"""Distance bounds from an earlier query: never above the true signed distance after a move, so
the points they leave out of a query are truly that far from the body, and the sides they
certify are the points' true sides."""

import numpy as np
import pytest
import torch
import trimesh

from physdrape.geometry.distance_bound import SLACK, DistanceBound
from physdrape.geometry.proximity import BodySurface


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    return BodySurface(torch.tensor(np.asarray(mesh.vertices)), torch.tensor(np.asarray(mesh.faces)))


def test_a_bound_never_exceeds_the_signed_distance_after_a_move(sphere):
    """Points inside and outside a sphere, moved up to 3 cm after the query: each bound is at
    most the point's signed distance, and the rows below a threshold hold every point that is
    below it (the others are proved farther)."""
    gen = torch.Generator().manual_seed(0)
    direction = torch.nn.functional.normalize(torch.randn(400, 3, generator=gen, dtype=torch.float64), dim=-1)
    radius = 0.07 + 0.08 * torch.rand(400, 1, generator=gen, dtype=torch.float64)
    points = direction * radius
    bound = DistanceBound.of(points, sphere.query(points).signed_distance)
    moved = points + 0.03 * torch.rand(400, 1, generator=gen, dtype=torch.float64) * torch.nn.functional.normalize(
        torch.randn(400, 3, generator=gen, dtype=torch.float64), dim=-1)
    truth = sphere.query(moved).signed_distance
    lower = bound.lower(moved)
    assert bool((lower <= truth + 1e-12).all())
    assert float((truth - lower).max()) > 0.01  # a bound, not the distance
    for threshold in (0.0, 2e-3, 1e-2):
        rows = bound.rows_below(moved, threshold)
        below = torch.nonzero(truth < threshold)[:, 0]
        assert set(below.tolist()) <= set(rows.tolist()) and 0 < len(rows) < 400
        assert bool((lower[rows] < threshold + SLACK).all())


def test_a_certified_side_is_the_true_side_and_uncertain_points_are_the_ones_that_may_have_crossed(sphere):
    gen = torch.Generator().manual_seed(1)
    direction = torch.nn.functional.normalize(torch.randn(600, 3, generator=gen, dtype=torch.float64), dim=-1)
    points = direction * (0.08 + 0.04 * torch.rand(600, 1, generator=gen, dtype=torch.float64))
    before = sphere.query(points).signed_distance
    moved = points + 0.02 * torch.rand(600, 1, generator=gen, dtype=torch.float64) * torch.nn.functional.normalize(
        torch.randn(600, 3, generator=gen, dtype=torch.float64), dim=-1)
    truth = sphere.query(moved).signed_distance
    side = DistanceBound.of(points, before).sign(moved)
    known = side != 0
    assert torch.equal(side[known] > 0, truth[known] > 0)  # never a wrong side
    crossed = (truth > 0) != (before > 0)
    assert crossed.any() and not (known & crossed).any()  # the points that crossed are never certified
    assert 0.3 < float(known.double().mean()) < 0.95  # most certified, not all
    moved_less = before.abs() - (moved - points).norm(dim=-1)
    assert torch.equal(known, moved_less > SLACK)


def test_update_and_part_replace_and_cut_rows():
    points, distance = torch.zeros(5, 3, dtype=torch.float64), torch.arange(5, dtype=torch.float64)
    bound = DistanceBound.of(points, distance)
    newer = bound.updated(torch.tensor([1, 3]), torch.ones(2, 3), torch.tensor([-1.0, -3.0]))
    torch.testing.assert_close(newer.distance, torch.tensor([0.0, -1.0, 2.0, -3.0, 4.0], dtype=torch.float64))
    torch.testing.assert_close(newer.at[[1, 3]], torch.ones(2, 3, dtype=torch.float64))
    assert torch.equal(bound.distance, distance)  # the original kept
    part = newer.part(1, 3)
    torch.testing.assert_close(part.distance, torch.tensor([-1.0, 2.0], dtype=torch.float64))
    torch.testing.assert_close(newer.select(torch.tensor([3, 0])).distance, torch.tensor([-3.0, 0.0], dtype=torch.float64))
    with pytest.raises(ValueError, match="shape"):
        part.lower(torch.zeros(3, 3))


def test_query_within_asks_only_the_rows_the_bound_leaves_within_the_threshold(sphere):
    gen = torch.Generator().manual_seed(2)
    points = torch.nn.functional.normalize(torch.randn(300, 3, generator=gen, dtype=torch.float64), dim=-1) * (
        0.09 + 0.05 * torch.rand(300, 1, generator=gen, dtype=torch.float64))
    body = torch.zeros(300, dtype=torch.int64)
    bound = DistanceBound.of(points, sphere.query(points).signed_distance)
    moved = points + 1e-3
    rows, query = sphere.query_within(moved, 5e-3, body_index=body, bound=bound)
    assert torch.equal(rows, bound.rows_below(moved, 5e-3)) and 0 < len(rows) < 300
    assert torch.equal(query.signed_distance, sphere.query(moved[rows]).signed_distance)
    every, plain = sphere.query_within(moved, 5e-3, body_index=body, bound=None)
    assert every is None and torch.equal(plain.signed_distance, sphere.query(moved).signed_distance)

"""Strain limiting of X_init: stretched edges brought under the bound, the rest untouched."""

import pytest
import torch

from physdrape.geometry.primitives import grid_sheet
from physdrape.geometry.strain_limit import limit_edge_stretch, max_edge_stretch
from physdrape.geometry.topology import undirected_edges


@pytest.fixture
def sheet():
    v, f = grid_sheet(10, 10, width=0.2, height=0.2)
    v = torch.as_tensor(v, dtype=torch.float64)
    e = torch.from_numpy(undirected_edges(f))
    return v, e, (v[e[:, 1]] - v[e[:, 0]]).norm(dim=-1)


def test_a_pulled_vertex_is_brought_back_under_the_bound(sheet):
    v, e, rest = sheet
    x = v.clone()
    x[55, 1] += 0.08  # one vertex pulled 8 cm out of a 2 cm grid: ~4x stretch
    assert max_edge_stretch(x, e, rest) > 3.5
    y = limit_edge_stretch(x, e, rest, max_stretch=1.5)
    assert max_edge_stretch(y, e, rest) < 1.5 * 1.01
    far = (v - v[55]).norm(dim=-1) > 0.1
    assert torch.equal(y[far], x[far])  # untouched away from the stretched patch


def test_within_bound_is_the_identity_and_batches_match(sheet):
    v, e, rest = sheet
    x = v * 1.2  # uniform 1.2x stretch, inside the bound
    assert torch.equal(limit_edge_stretch(x, e, rest, max_stretch=1.5), x)
    pulled = v.clone()
    pulled[12, 1] += 0.06
    batch = torch.stack([x, pulled])
    out = limit_edge_stretch(batch, e, rest, max_stretch=1.5)
    assert torch.allclose(out[1], limit_edge_stretch(pulled, e, rest, max_stretch=1.5), atol=1e-12)


def test_rejects_bad_arguments(sheet):
    v, e, rest = sheet
    with pytest.raises(ValueError, match="max_stretch"):
        limit_edge_stretch(v, e, rest, max_stretch=0.9)
    with pytest.raises(ValueError, match="rest_lengths"):
        limit_edge_stretch(v, e, rest[:-1])

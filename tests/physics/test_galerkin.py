"""The Galerkin product's launch against G · K formed with scipy, entry by entry."""

import numpy as np
import pytest
import scipy.sparse as sp
import torch
from device_params import DEVICES

from physdrape.physics.galerkin import GalerkinProduct


@pytest.mark.parametrize("device", DEVICES)
def test_galerkin_product_writes_each_stored_entry_of_g_times_the_blocks(device):
    rng = np.random.default_rng(0)
    pairs, rows, garments = 40, 12, 3
    operator = sp.random(rows, pairs, density=0.3, random_state=1, format="csr")
    starts = np.array([0, pairs, 2 * pairs])  # each garment's pairs, one garment after another
    blocks = rng.normal(size=(garments * pairs, 3, 3))
    size = garments * rows * 9
    destination = rng.permutation(size).reshape(garments, rows * 9)
    destination[:, rng.random(rows * 9) < 0.3] = -1  # entries not stored (a band's upper triangle)
    destination[:, 9 * 5:9 * 6] = -1  # a coarse block no garment stores
    expected = np.full(size, 7.0)
    for g in range(garments):
        formed = (operator @ blocks[starts[g]:starts[g] + pairs].reshape(pairs, 9)).reshape(-1)
        stored = destination[g] >= 0
        expected[destination[g, stored]] = formed[stored]

    product = GalerkinProduct(operator, starts, destination, torch.device(device))
    out = torch.full((size,), 7.0, dtype=torch.float64, device=device)
    product(torch.from_numpy(blocks).to(device), out)
    np.testing.assert_allclose(out.cpu().numpy(), expected, rtol=1e-12, atol=1e-12)
    assert product.num_blocks == rows - 1


def test_galerkin_product_rejects_what_it_cannot_form():
    operator = sp.random(4, 6, density=0.5, random_state=0, format="csr")
    with pytest.raises(ValueError, match="destinations"):
        GalerkinProduct(operator, np.array([0]), np.zeros((1, 35), np.int64), torch.device("cpu"))
    product = GalerkinProduct(operator, np.array([0]), np.zeros((1, 36), np.int64), torch.device("cpu"))
    with pytest.raises(ValueError, match="float64"):
        product(torch.zeros(6, 3, 3), torch.zeros(36, dtype=torch.float64))

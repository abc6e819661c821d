"""The devices the device tests run on: the CPU always, CUDA where this machine has a GPU (the
CUDA cases are skipped elsewhere, with the reason)."""

from __future__ import annotations

import pytest
import torch

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")

#: `pytest.mark.parametrize("device", DEVICES)`: "cpu", and "cuda" skipped without a GPU.
DEVICES = [pytest.param("cpu", id="cpu"), pytest.param("cuda", id="cuda", marks=needs_cuda)]

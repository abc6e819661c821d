"""The devices the device tests run on: the CPU always, CUDA where this machine has a GPU (the
CUDA cases are skipped elsewhere, with the reason); and what torch.compile's tests need."""

from __future__ import annotations

import os
import shutil

import pytest
import torch

needs_cuda = pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device on this machine")

#: `pytest.mark.parametrize("device", DEVICES)`: "cpu", and "cuda" skipped without a GPU.
DEVICES = [pytest.param("cpu", id="cpu"), pytest.param("cuda", id="cuda", marks=needs_cuda)]

#: torch.compile on the CPU (TorchInductor) builds C++: the compiled network's tests need a compiler.
needs_compiler = pytest.mark.skipif(shutil.which(os.environ.get("CXX", "g++")) is None and shutil.which("c++") is None,
                                    reason="no C++ compiler on this machine (torch.compile's CPU backend needs one)")

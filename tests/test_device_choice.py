"""`physdrape.devices.resolve_device`: what a caller may ask for, and the errors that say how to
fix what this machine cannot do."""

from __future__ import annotations

import pytest
import torch
from device_params import needs_cuda

from physdrape.devices import DeviceError, available_devices, resolve_device


@pytest.mark.parametrize("spec", ["cpu", None, torch.device("cpu")])
def test_cpu_is_always_there(spec):
    assert resolve_device(spec) == torch.device("cpu")
    assert available_devices()[0] == "cpu"


@pytest.mark.parametrize("spec, words", [("mps", "not supported"), ("meta", "not supported"),
                                         ("gpu", "not a device name"), ("cuda:x", "not a device name")])
def test_unsupported_and_malformed_devices_are_refused(spec, words):
    with pytest.raises(DeviceError, match=words):
        resolve_device(spec)


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has a CUDA device")
@pytest.mark.parametrize("spec", ["cuda", "cuda:0", torch.device("cuda", 1)])
def test_cuda_without_a_gpu_names_the_fix(spec):
    with pytest.raises(DeviceError) as info:
        resolve_device(spec)
    message = str(info.value)
    assert "device='cpu'" in message
    assert ("CPU-only build" in message and "install a CUDA build of torch" in message) or "sees no GPU" in message
    assert "cuda" not in available_devices()


@needs_cuda
def test_cuda_resolves_to_an_indexed_device():
    dev = resolve_device("cuda")
    assert dev.type == "cuda" and dev.index == torch.cuda.current_device()
    assert torch.zeros(1, device=dev).device == dev
    with pytest.raises(DeviceError, match="pick one of them"):
        resolve_device(f"cuda:{torch.cuda.device_count()}")

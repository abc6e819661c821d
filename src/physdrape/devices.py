"""Where PhysDrape computes: the torch device of the model, the solver, the collision handler, the
body queries and the drape pipeline's output.

PhysDrape runs on "cpu" (the default) or on a CUDA GPU: its body queries are NVIDIA Warp kernels,
which compile for these two. `resolve_device` turns what a caller asks for into a `torch.device`
at the edge (the API's `Draper`, the `Trainer`) and says how to fix a request that cannot be met.
"""

from __future__ import annotations

import torch

from physdrape.warp_runtime import warp

__all__ = ["DeviceError", "resolve_device", "available_devices"]

_TORCH_INSTALL = "https://pytorch.org/get-started/locally/"


class DeviceError(ValueError):
    """A device PhysDrape cannot run on; the message says why and what to do."""


def available_devices() -> list[str]:
    """The device types this machine can run PhysDrape on: ["cpu"], plus "cuda" when torch sees a GPU."""
    return ["cpu"] + (["cuda"] if torch.cuda.is_available() else [])


def resolve_device(device: str | torch.device | None = "cpu") -> torch.device:
    """A validated device from "cpu", "cuda", "cuda:N" or a `torch.device` (None = "cpu").

    "cuda" names the current CUDA device with its index ("cuda:0"), so that it compares equal to
    the device of the tensors placed on it.

    Raises:
        DeviceError: an unknown or unsupported device type; CUDA asked for on a CPU-only torch
            build or on a machine where torch (or Warp) sees no GPU; cuda:N past the last GPU.
    """
    if device is None:
        return torch.device("cpu")
    try:
        dev = torch.device(device)
    except (RuntimeError, TypeError):
        raise DeviceError(f"device {device!r} is not a device name: use 'cpu', 'cuda' or 'cuda:N'") from None
    if dev.type == "cpu":
        return torch.device("cpu")
    if dev.type != "cuda":
        raise DeviceError(f"device {device!r} is not supported: PhysDrape runs on 'cpu' or 'cuda' (its body "
                          "queries are NVIDIA Warp kernels, which compile for these two)")
    if torch.version.cuda is None:
        raise DeviceError(f"device {device!r} asks for CUDA, but the installed torch {torch.__version__} is a "
                          f"CPU-only build: install a CUDA build of torch ({_TORCH_INSTALL}) on a machine with an "
                          "NVIDIA GPU, or use device='cpu'")
    if not torch.cuda.is_available():
        raise DeviceError(f"device {device!r} asks for CUDA, but torch {torch.__version__} (CUDA "
                          f"{torch.version.cuda}) sees no GPU: check the GPU and its driver (`nvidia-smi`) and that "
                          "CUDA_VISIBLE_DEVICES does not hide it, or use device='cpu'")
    count = torch.cuda.device_count()
    index = torch.cuda.current_device() if dev.index is None else dev.index
    if index >= count:
        raise DeviceError(f"device {device!r}: this machine has {count} CUDA device(s) (cuda:0 … "
                          f"cuda:{count - 1}); pick one of them, or 'cuda' for the current one")
    wp = warp()
    if not wp.is_cuda_available():
        raise DeviceError(f"device {device!r}: torch sees a GPU, but NVIDIA Warp {wp.config.version} cannot use "
                          "CUDA (a Warp build without CUDA, or a driver older than Warp needs): reinstall "
                          "warp-lang from PyPI (its wheels include CUDA) and update the driver, or use device='cpu'")
    return torch.device("cuda", index)

"""The one place PhysDrape starts NVIDIA Warp (used by the body-surface queries, the solver's
preconditioner blocks, the garment intersection tests, and Anny): initialised once, without its
banner on stdout, where the CLI prints JSON, nor its notice on stderr that a machine without an
NVIDIA driver has no GPU (the CPU is what such a machine drapes on); the stream Warp work on a
torch device runs on; and `defined_once`, the cache of the functions that define a module's
kernels, with `load_all_kernels` for work about to run on several threads."""

from __future__ import annotations

import contextlib
import functools
import os
import sys
import tempfile
import threading
from collections.abc import Callable
from typing import TypeVar

import torch

R = TypeVar("R")

_DEFINING = threading.RLock()
_DEFINERS: list[Callable[[], object]] = []  # every `defined_once` function, in import order
_LOADED: set[tuple[str, str]] = set()  # (module, device) pairs `load_all_kernels` has loaded


def _once(make: Callable[[], R]) -> Callable[[], R]:
    """make() run once per process, its result cached, under one lock (reentrant: a definition
    may ask for another's kernels)."""
    done: list[R] = []

    @functools.wraps(make)
    def once() -> R:
        if not done:
            with _DEFINING:
                if not done:
                    done.append(make())
        return done[0]

    return once


def defined_once(define: Callable[[], R]) -> Callable[[], R]:
    """`define` (no arguments: it defines the Warp kernels of the Python module it lives in and
    returns them) run once per process, its result cached: a second definition of a module's
    kernels, on another thread, would make Warp rebuild and reload that module while a kernel of
    it runs. Registered for `load_all_kernels`."""
    once = _once(define)
    _DEFINERS.append(once)
    return once


def load_all_kernels(device: str = "cpu") -> None:
    """Define the kernels of every imported `defined_once` function and load their modules on
    `device`, each once per process. Warp loads a module on its first launch, and two threads
    that both launch a kernel of a module not loaded yet can crash the process (a segmentation
    fault on the CPU, seen with two threads' first strain-force launches; none once the module
    was loaded beforehand): work about to be split between threads calls this first."""
    if all((once.__module__, device) in _LOADED for once in _DEFINERS):
        return
    wp = warp()
    with _DEFINING:
        for once in _DEFINERS:
            if (once.__module__, device) not in _LOADED:
                once()
                wp.load_module(once.__module__, device=device)
                _LOADED.add((once.__module__, device))


@_once
def warp():
    """The initialised `warp` module (its log level raised to warnings first)."""
    import warp as wp  # noqa: PLC0415  (heavy import, only needed for queries)

    wp.config.log_level = max(wp.config.log_level, wp.LOG_WARNING)
    with _stderr_without(NO_DRIVER_NOTICE):
        wp.init()  # a no-op if something initialised it already
    return wp


#: What Warp's native start-up prints on a machine without an NVIDIA driver (every CPU-only
#: laptop): not passed on.
NO_DRIVER_NOTICE = "Could not find or load the NVIDIA CUDA driver"


@contextlib.contextmanager
def _stderr_without(notice: str):
    """Run the block with the process's stderr (file descriptor 2, which native code writes to)
    captured, then pass on every captured line but those containing `notice`. Where descriptor 2
    cannot be duplicated (an embedded interpreter), the block runs with stderr as it is."""
    try:
        if sys.stderr is not None:
            sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError):
        saved = None
    if saved is None:
        yield
        return
    with tempfile.TemporaryFile() as capture:
        os.dup2(capture.fileno(), 2)
        try:
            yield
        finally:  # also when the block raises: what it printed is passed on
            os.dup2(saved, 2)
            os.close(saved)
            capture.seek(0)
            text = capture.read().decode("utf-8", errors="replace")
            kept = "".join(line for line in text.splitlines(keepends=True) if notice not in line)
            if kept and sys.stderr is not None:
                sys.stderr.write(kept)
                sys.stderr.flush()


def launch_arg(tensor: torch.Tensor, dtype):
    """`tensor` as a Warp launch argument of element type `dtype` (e.g. ``wp.vec3d``), without a
    copy: an array descriptor (``wp.from_torch(..., return_ctype=True)``), cheaper to make than a
    ``wp.array`` and launched alike; it keeps the tensor alive while it lives."""
    return warp().from_torch(tensor, dtype=dtype, requires_grad=False, return_ctype=True)


def torch_stream(device: torch.device):
    """A context running Warp work on torch's current stream of CUDA `device`, so that it is
    ordered with the torch ops that write its inputs and read its outputs; nothing on the CPU."""
    if device.type == "cuda":
        wp = warp()
        return wp.ScopedStream(wp.stream_from_torch(device))
    return contextlib.nullcontext()

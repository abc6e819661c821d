"""Telling the user about slow phases: a line on stderr when a phase has run for a few seconds,
and one when it ends, so that no long operation is silent and no short one is noisy; progress
bars that redraw on a terminal and log sparingly into a file."""

from __future__ import annotations

import contextlib
import sys
import threading
import time
from collections.abc import Callable, Iterator
from pathlib import Path

#: A phase that runs longer than this [s] is announced.
ANNOUNCE_AFTER_S = 5.0
#: Seconds between a progress bar's updates where its stream is not a terminal (a log file, a
#: cluster job's output, a pipe): there every update stays in the file, so a training run of
#: hours logs a few hundred lines instead of tqdm's ten a second.
LOG_UPDATE_EVERY_S = 30.0


@contextlib.contextmanager
def slow_phase(message: str, *, after: float = ANNOUNCE_AFTER_S, done: Callable[[], str] | None = None,
               stream=None) -> Iterator[None]:
    """Run the block; if it is still running after `after` seconds, print ``[physdrape] message``,
    and when it ends ``[physdrape] ... done in T s`` (plus `done()`'s text, e.g. a cache size)."""
    out = sys.stderr if stream is None else stream
    announced = threading.Event()

    def announce() -> None:
        announced.set()
        print(f"[physdrape] {message} ...", file=out, flush=True)

    timer = threading.Timer(after, announce)
    timer.daemon = True
    start = time.perf_counter()
    timer.start()
    try:
        yield
    finally:
        timer.cancel()
        if announced.is_set():
            extra = f"; {done()}" if done is not None else ""
            print(f"[physdrape] ... done in {time.perf_counter() - start:.0f} s{extra}", file=out, flush=True)


def iteration_progress(label: str, *, every: float = ANNOUNCE_AFTER_S, stream=None,
                       clock: Callable[[], float] = time.perf_counter) -> Callable:
    """A per-iteration callback for a long iterative solve (the oracle's `relax(callback=...)`):
    at most once every `every` seconds it prints ``[physdrape] label: iteration k, residual r,
    E e J, t s`` from the iteration's record (its iteration, residual, energy and wall fields), so a
    solve of minutes says where it is."""
    out = sys.stderr if stream is None else stream
    last = [clock()]

    def report(record, _x=None) -> None:
        now = clock()
        if now - last[0] >= every:
            last[0] = now
            print(f"[physdrape] {label}: iteration {record.iteration}, residual {record.residual:.3g}, "
                  f"E {record.energy:.5g} J, {record.wall:.0f} s", file=out, flush=True)

    return report


def directory_size(path) -> str:
    """The total size of the files under `path`, e.g. "790 MB" (for cache messages)."""
    total = sum(p.stat().st_size for p in Path(path).rglob("*") if p.is_file())
    return f"{total / 1e6:.0f} MB" if total < 1e9 else f"{total / 1e9:.1f} GB"


def progress_bar(*, total: int, desc: str, unit: str = "it", initial: int = 0, disable: bool = False, stream=None):
    """A tqdm progress bar on `stream` (default stderr): redrawn up to ten times a second on a
    terminal, updated at most every `LOG_UPDATE_EVERY_S` seconds elsewhere."""
    from tqdm import tqdm  # noqa: PLC0415  (only where a bar is shown)

    out = sys.stderr if stream is None else stream
    interactive = bool(getattr(out, "isatty", lambda: False)())
    every = 0.1 if interactive else LOG_UPDATE_EVERY_S
    return tqdm(total=total, initial=initial, desc=desc, unit=unit, file=out, disable=disable, dynamic_ncols=True,
                mininterval=every, maxinterval=max(10.0, every))

"""What the subcommands share: the CLI's error, the checks of output paths, and putting a finished
output folder in place as a whole (never a mix of two runs, never half of one)."""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import tempfile
import threading
from collections.abc import Iterator
from pathlib import Path

from physdrape.atomic import replace_directory


class CLIError(ValueError):
    """A bad flag or file; the message names the problem and the fix (exit code 2)."""


def check_out_dir(out: Path, force: bool, *, replaces: str | None = None) -> None:
    """Refuse an existing non-empty output directory without --force, and unwritable places.

    replaces: the file an earlier run's output folder always holds (e.g. report.json): --force
    then replaces only such a folder as a whole, never one that holds something else."""
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out} exists and is not a directory; choose another path")
    if out.is_dir() and any(out.iterdir()):
        if not force:
            raise CLIError(f"--out {out} already holds files; pass --force to replace them or choose another --out")
        if replaces is not None:
            _check_replaceable(out, replaces)
    probe = out if out.exists() else out.parent
    while not probe.exists():
        probe = probe.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise CLIError(f"--out {out}: {probe} is not writable; choose a directory you can write to")


def _check_replaceable(out: Path, marker: str) -> None:
    """--force replaces `out` as a whole: only an earlier run's output, never the working directory."""
    here = Path.cwd().resolve()
    if out.resolve() == here or out.resolve() in here.parents:
        raise CLIError(f"--out {out} holds the current directory; --force replaces the whole folder: choose "
                       "another --out")
    if not (out / marker).is_file():
        raise CLIError(f"--out {out} holds files but no {marker}, so it is not an earlier run's output; --force "
                       "replaces the whole folder: choose another --out (or empty this one)")


def safe_name(name: str) -> str:
    """`name` as a file-name component (letters, digits, - _ . only; at most 60 characters)."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)[:60]


@contextlib.contextmanager
def deferred_interrupt(note: str) -> Iterator[None]:
    """Hold Ctrl-C (SIGINT) back while the block runs, so that it is never cut in half; a Ctrl-C
    that arrived meanwhile is raised after it as ``KeyboardInterrupt(note)`` (`note` says what
    the block completed). Outside the main thread (no signal handlers there) the block just runs."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    caught: list[int] = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: caught.append(signum))
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, previous if previous is not None else signal.default_int_handler)
    if caught:
        raise KeyboardInterrupt(note)


@contextlib.contextmanager
def staged_directory(out: Path) -> Iterator[Path]:
    """A new temporary folder beside `out` to write a run's outputs into, then `commit_directory`
    it. Always removed at the end; when `out` was not committed, so are the parent folders this
    created for it (an interrupted or failed run leaves nothing behind)."""
    missing = [p for p in (out.parent, *out.parent.parents) if not p.exists()]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        yield tmp
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
        if not out.exists():
            for parent in missing:  # innermost first; only folders still empty
                with contextlib.suppress(OSError):
                    parent.rmdir()


def commit_directory(tmp: Path, out: Path, *, force: bool, replaces: str | None = None) -> None:
    """Put the finished folder `tmp` (beside `out`) in place of `out` as a whole.

    `physdrape.atomic.replace_directory` swaps them, so at every moment `out` is either the
    earlier run's folder or this one's, never a mix. Ctrl-C is held back until this is done. An
    existing non-empty `out` is refused as `check_out_dir` does."""
    with deferred_interrupt(f"{out} was written in full before stopping"):
        if out.exists() or out.is_symlink():
            if not out.is_dir() or out.is_symlink():
                raise CLIError(f"--out {out} exists and is not a directory; choose another path")
            check_out_dir(out, force, replaces=replaces)
        replace_directory(tmp, out)


def process_device(name: str) -> str:
    """The device of this process: `name` ("cpu", "cuda", "cuda:N"), with "cuda" meaning the GPU of
    the process's local rank under torchrun (LOCAL_RANK), so each process of a node gets its own."""
    if name == "cuda" and "LOCAL_RANK" in os.environ:
        return f"cuda:{int(os.environ['LOCAL_RANK'])}"
    return name


def add_device_argument(parser) -> None:
    """--device {cpu, cuda, cuda:N} (default cpu)."""
    parser.add_argument("--device", default="cpu", help="where the model runs: cpu (default), cuda (under torchrun: "
                        "the GPU of each process's LOCAL_RANK) or cuda:N")

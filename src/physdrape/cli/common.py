"""What the subcommands share: the CLI's error and the checks of output paths."""

from __future__ import annotations

import os
from pathlib import Path


class CLIError(ValueError):
    """A bad flag or file; the message names the problem and the fix (exit code 2)."""


def check_out_dir(out: Path, force: bool) -> None:
    """Refuse an existing non-empty output directory without --force, and unwritable places."""
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out} exists and is not a directory; choose another path")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise CLIError(f"--out {out} already holds files; pass --force to overwrite them or choose another --out")
    probe = out if out.exists() else out.parent
    while not probe.exists():
        probe = probe.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise CLIError(f"--out {out}: {probe} is not writable; choose a directory you can write to")


def safe_name(name: str) -> str:
    """`name` as a file-name component (letters, digits, - _ . only; at most 60 characters)."""
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)[:60]

"""Where a result came from: the versions of PhysDrape and its dependencies, the platform and the
git commit, recorded beside every number a command writes under results/."""

from __future__ import annotations

import platform
import subprocess
from pathlib import Path

import numpy as np
import torch


def provenance() -> dict:
    """Versions of PhysDrape, its dependencies and the platform, and the git commit (dirty or not)."""
    import physdrape

    def git(*args: str) -> str | None:
        try:
            return subprocess.run(["git", *args], cwd=Path(__file__).parent, capture_output=True, check=False,
                                  text=True, timeout=5).stdout.strip()
        except (OSError, subprocess.SubprocessError):
            return None

    commit, status = git("rev-parse", "HEAD"), git("status", "--porcelain")
    return {"physdrape": physdrape.__version__, "torch": torch.__version__, "numpy": np.__version__,
            "python": platform.python_version(), "git_commit": commit or None,
            "git_dirty": bool(status) if status is not None else None, "platform": platform.platform()}

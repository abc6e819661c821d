"""The procedural garments that drapes ask for by name (CATEGORY:SEED), kept on disk.

Generating one costs 1-4 s (remeshing, shrink-wrapping, validation); a garment asked for again,
by a later process, is read back in milliseconds from
``~/.cache/physdrape/generated_garments/<code key>/<category>_<seed>.ply`` (binary PLY, written
atomically). The code key digests the split format, the versions of the libraries a garment's
bytes depend on and the source of the installed PhysDrape package, so a garment made by other code
is never read back: another key is another folder, and writing into one removes the others'
(kept garments of older code). A cache that cannot be written (a read-only home) only means
generating each time.
"""

from __future__ import annotations

import functools
import hashlib
import importlib.metadata
import shutil
from pathlib import Path

import numpy as np

from physdrape.garments.catalogue import generate_valid
from physdrape.garments.io import read_ply, write_ply
from physdrape.garments.split import SPLIT_FORMAT
from physdrape.geometry.mesh import MeshError
from physdrape.user_cache import cache_root

__all__ = ["CACHE_FOLDER", "code_key", "generated_garment"]

#: The cache's folder under `physdrape.user_cache.cache_root()`.
CACHE_FOLDER = "generated_garments"
#: The libraries whose versions a garment's bytes depend on (the body model, remeshing, queries).
_LIBRARIES = ("anny", "gpytoolbox", "warp-lang", "numpy", "scipy", "torch")


@functools.cache
def code_key() -> str:
    """16 hex digits naming the code that makes the garments: the split format, the libraries'
    versions and every source file of the installed PhysDrape package."""
    digest = hashlib.sha256(SPLIT_FORMAT.encode())
    for lib in _LIBRARIES:
        try:
            digest.update(f"{lib}={importlib.metadata.version(lib)};".encode())
        except importlib.metadata.PackageNotFoundError:
            digest.update(f"{lib}=;".encode())
    package = Path(__file__).resolve().parents[1]
    for source in sorted(package.rglob("*.py")):
        digest.update(source.relative_to(package).as_posix().encode())
        digest.update(source.read_bytes())
    return digest.hexdigest()[:16]


def generated_garment(category: str, seed: int, *, root: Path | None = None) -> tuple[str, np.ndarray, np.ndarray]:
    """The garment `category`:`seed` (`garments.catalogue.generate_valid`) as (name, verts (V, 3)
    float64 [m], faces (F, 3) int64): read from the cache under `root` (default: PhysDrape's
    cache root) when it holds it for this code, generated and written there otherwise."""
    name = f"{category}_{int(seed)}"
    folder = (cache_root() if root is None else Path(root)) / CACHE_FOLDER
    path = folder / code_key() / f"{name}.ply"
    if path.is_file():
        try:
            verts, faces = read_ply(path)
            return name, verts, faces
        except (MeshError, OSError, ValueError, IndexError):
            pass  # unreadable (a disk error, a foreign file): made again below
    garment, _ = generate_valid(category, int(seed))
    try:
        write_ply(path, garment.verts, garment.faces)
        for other in folder.iterdir():
            if other.is_dir() and other.name != path.parent.name:
                shutil.rmtree(other, ignore_errors=True)
    except OSError:
        pass  # no writable cache: the garment is generated again next time
    return name, garment.verts, garment.faces

"""The fixed, seeded garment split: 600 training and 30 test procedural tops, and as many
procedural outfits (a top over trousers, `garments.outfits`) for training as asked for.

    python -m physdrape.garments.split --out DIR [--seed 0] [--num-train 600] [--num-test 30]
        [--num-outfits N] [--workers N]

Writes DIR/train/NNNN_<category>.ply, DIR/test/NNNN_<category>.ply, DIR/outfits/NNNN_outfit.ply
(binary PLY, float64, deterministic bytes) and DIR/manifest.json (parameters, attempt,
vertex/face counts, sha256). The subsets draw from disjoint seed streams; the tops' categories
cycle, so every category is in the test set. The outfits are not part of the protocol's fixed
sizes: a split holds the first `num_outfits` of them that any caller asked for, and asking for more
adds them.

Every garment is a pure function of (seed, subset, index), so a split directory may hold any part
of the split. Generation adds the garments that are missing (or whose file no longer matches its
sha256), each file written atomically and recorded in the manifest (also written atomically, at
least once a second and whenever generation stops), so an interrupted generation resumes where it
stopped; `load_or_generate` makes only the garments its caller reads. Processes generating into
the same directory take turns (a lock on the directory). Re-running with the same seed reproduces
every file byte for byte (same machine and library versions; see the manifest's `versions`, and a
garment's own `versions` where it was added under others), whatever the caller's torch threads.
"""

from __future__ import annotations

import argparse
import contextlib
import importlib.metadata
import json
import multiprocessing as mp
import os
import signal
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import torch

from physdrape.atomic import write_text
from physdrape.garments.canonical import CanonicalBody, canonical_body
from physdrape.garments.catalogue import OUTFIT, generate_valid
from physdrape.garments.generator import COLLISION_MARGIN, GarmentCategory, GarmentParams, GarmentTemplate
from physdrape.garments.io import read_ply, sha256_file, write_ply
from physdrape.garments.outfits import OutfitParams
from physdrape.progress import progress_bar

try:  # POSIX: processes generating into one directory take turns
    import fcntl
except ImportError:  # pragma: no cover - Windows: no lock
    fcntl = None

__all__ = ["make_split", "load_split", "load_or_generate", "read_manifest", "split_entries", "DEFAULT_SEED",
           "SPLIT_FORMAT"]

#: Bumped whenever the generator's output changes; a split of another format is refused.
SPLIT_FORMAT = "physdrape-garment-split/3"  # 2: remeshing cleans short edges and slivers; 3: garments validated
# with the exact triangle test (draws that Warp's coplanarity snap called self-intersecting are kept)

DEFAULT_SEED = 0
DEFAULT_SIZES = {"train": 600, "test": 30}
_SUBSETS = {"train": 1, "test": 2, "outfits": 3}
_GENERATE_HINT = "python -m physdrape.garments.split --out {dir}"


def split_entries(seed: int, num_train: int, num_test: int, num_outfits: int = 0) -> list[dict]:
    """The (subset, index, category, garment seed) of every garment of a split; entry (subset,
    index) depends on `seed` only, not on the subset sizes."""
    cats = list(GarmentCategory)
    out = []
    for subset, n in (("train", num_train), ("test", num_test), ("outfits", num_outfits)):
        for i in range(n):
            gseed = int(np.random.SeedSequence([int(seed), _SUBSETS[subset], i]).generate_state(1)[0])
            category = OUTFIT if subset == "outfits" else cats[i % len(cats)].value
            out.append(dict(subset=subset, index=i, category=category, seed=gseed))
    return out


def _file(entry: dict) -> str:
    return f"{entry['subset']}/{entry['index']:04d}_{entry['category']}.ply"


def _body() -> CanonicalBody:
    """The canonical body, built with one torch thread when this process has not built it yet:
    Anny's forward pass sums in another order on more threads, and those last-bit differences
    reach the garments' bytes, so the split would otherwise depend on the caller's thread count."""
    if canonical_body.cache_info().currsize == 0:
        threads = torch.get_num_threads()
        torch.set_num_threads(1)
        try:
            canonical_body()
        finally:
            torch.set_num_threads(threads)
    return canonical_body()


def _make_one(job: tuple[dict, str, float]) -> dict:
    """Generate one entry's garment into out_dir; its manifest row."""
    entry, out_dir, target_edge = job
    g, attempt = generate_valid(entry["category"], entry["seed"], target_edge=target_edge, body=_body())
    digest = write_ply(Path(out_dir) / _file(entry), g.verts, g.faces)
    return dict(
        entry, file=_file(entry), attempt=attempt, params=g.params.to_dict(), num_verts=g.num_verts,
        num_faces=g.num_faces, sha256=digest,
    )


def _versions() -> dict:
    out = {}
    for pkg in ("anny", "gpytoolbox", "warp-lang", "numpy", "scipy"):
        try:
            out[pkg] = importlib.metadata.version(pkg)
        except importlib.metadata.PackageNotFoundError:
            out[pkg] = None
    return out


def read_manifest(split_dir: str | os.PathLike) -> dict | None:
    """The manifest of the split in `split_dir` (None when there is none yet).

    Raises:
        ValueError when it is not valid JSON or is of another `SPLIT_FORMAT`.
    """
    path = Path(split_dir) / "manifest.json"
    if not path.is_file():
        return None
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise ValueError(f"{path} is not valid JSON ({exc}): delete it and generate the split again "
                         f"({_GENERATE_HINT.format(dir=split_dir)})") from exc
    if manifest.get("format") != SPLIT_FORMAT:
        raise ValueError(f"{path} is a split of format {manifest.get('format')!r}, this version reads "
                         f"{SPLIT_FORMAT!r}: generate it into another directory ({_GENERATE_HINT.format(dir='DIR')})")
    return manifest


def _check_same_split(manifest: dict, split_dir: Path, **wanted) -> None:
    """Refuse to add garments of another split (seed, sizes, edge length) to `split_dir`."""
    have = {k: manifest.get(k) for k in wanted}
    if have != wanted:
        raise ValueError(
            f"{split_dir} holds the split {have}, not the requested {wanted}: ask for the same "
            f"parameters or generate into another directory")


def _is_present(split_dir: Path, row: dict | None, entry: dict) -> bool:
    """Whether `entry`'s garment is recorded in the manifest (`row`) and its file is intact."""
    if row is None or any(row.get(k) != v for k, v in entry.items()) or row.get("file") != _file(entry):
        return False
    path = split_dir / row["file"]
    return path.is_file() and sha256_file(path) == row.get("sha256")


@contextlib.contextmanager
def _locked(split_dir: Path, *, say: bool) -> Iterator[None]:
    """Hold an exclusive lock on split_dir (the directory itself) while generating, so processes
    generating into it take turns."""
    if fcntl is None:
        yield
        return
    fd = os.open(split_dir, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            if say:
                print(f"[physdrape] waiting for another process generating the garment split in {split_dir}",
                      file=sys.stderr, flush=True)
            fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _start_worker() -> None:
    """Pool workers leave Ctrl-C to the parent, which stops them and keeps the manifest, and run
    torch on one thread: a forked child entering a parallel region of the OpenMP pool its parent
    started would wait forever (the outfits' layer check runs torch)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    torch.set_num_threads(1)


@contextlib.contextmanager
def _runner(workers: int) -> Iterator:
    """A map of `_make_one` over jobs yielding rows as they finish: in this process, or in a pool
    of `workers` processes (started here, before any progress bar thread)."""
    if workers <= 1:
        yield lambda jobs: map(_make_one, jobs)
        return
    method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
    if method == "fork":
        _body()  # built once here, shared by the forked workers
    with mp.get_context(method).Pool(workers, initializer=_start_worker) as pool:
        yield lambda jobs: pool.imap_unordered(_make_one, jobs)


def _write_manifest(split_dir: Path, manifest: dict, rows: dict) -> None:
    order = {s: k for k, s in enumerate(_SUBSETS)}
    manifest["garments"] = sorted(rows.values(), key=lambda r: (order[r["subset"]], r["index"]))
    write_text(split_dir / "manifest.json", json.dumps(manifest, indent=1, sort_keys=True) + "\n")


def make_split(
    out_dir: str | os.PathLike,
    *,
    seed: int = DEFAULT_SEED,
    num_train: int = DEFAULT_SIZES["train"],
    num_test: int = DEFAULT_SIZES["test"],
    num_outfits: int = 0,
    target_edge: float = 0.015,
    subset: str | None = None,
    count: int | None = None,
    workers: int | None = None,
    progress: bool = False,
) -> dict:
    """Generate the split's missing garments into `out_dir`; returns the manifest (also written).

    Garments already recorded with an intact file are kept; the others are generated, in
    parallel, and recorded as they finish, so an interrupted call resumes where it stopped.

    Args:
        out_dir: split directory (created).
        seed: split seed; every garment is a pure function of it and its (subset, index).
        num_train, num_test: subset sizes (the paper's protocol: 600 / 30); an existing split
            directory must have been made with the same sizes, seed and target_edge.
        num_outfits: the outfits asked for; the split records the most any call asked for.
        target_edge: garment edge length [m].
        subset: generate only this subset ("train" / "test" / "outfits"); None: all three.
        count: generate only the first `count` garments of each chosen subset; None: all.
        workers: processes (default `os.cpu_count()`; results do not depend on it).
        progress: print where the split goes and how many garments are missing, and a progress bar
            (stderr), when any are.
    """
    if subset is not None and subset not in _SUBSETS:
        raise ValueError(f"subset must be one of {sorted(_SUBSETS)} or None, got {subset!r}")
    if count is not None and count < 0:
        raise ValueError(f"count must be ≥ 0 or None, got {count}")
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    params = dict(seed=int(seed), num_train=int(num_train), num_test=int(num_test), target_edge=float(target_edge))
    wanted = [e for e in split_entries(seed, num_train, num_test, num_outfits)
              if subset in (None, e["subset"]) and (count is None or e["index"] < count)]
    with _locked(out_dir, say=progress):
        manifest = read_manifest(out_dir)
        versions = _versions()
        if manifest is None:
            manifest = dict(params, format=SPLIT_FORMAT, collision_margin=COLLISION_MARGIN, versions=versions,
                            units="m, y-up, canonical Anny body (phenotypes 0.5, rest pose)", garments=[])
        else:
            _check_same_split(manifest, out_dir, **params)
        manifest["num_outfits"] = max(int(manifest.get("num_outfits", 0)), int(num_outfits))
        sizes = {s: manifest[f"num_{s}"] for s in _SUBSETS}
        rows = {(r["subset"], r["index"]): r for r in manifest["garments"]}
        missing = [e for e in wanted if not _is_present(out_dir, rows.get((e["subset"], e["index"])), e)]
        if not missing and (out_dir / "manifest.json").is_file():
            return manifest
        workers = max(1, min((os.cpu_count() or 1) if workers is None else workers, len(missing)))
        if progress:
            print(f"[physdrape] garment split in {out_dir}: {len(missing)} of the {len(wanted)} garments asked for "
                  f"are missing ({sum(sizes.values())} in the split); generating them with {workers} "
                  f"process{'es' if workers > 1 else ''}", file=sys.stderr, flush=True)
        jobs = [(e, str(out_dir), float(target_edge)) for e in missing]
        with _runner(workers) as run_all:
            bar = progress_bar(total=len(missing), unit="garment", desc="garment split", disable=not progress)
            written = time.monotonic()
            try:
                for row in run_all(jobs):
                    if versions != manifest["versions"]:
                        row["versions"] = versions
                    rows[(row["subset"], row["index"])] = row
                    bar.update(1)
                    if time.monotonic() - written > 1.0:
                        _write_manifest(out_dir, manifest, rows)
                        written = time.monotonic()
            finally:
                bar.close()
                _write_manifest(out_dir, manifest, rows)
    return manifest


def load_split(
    split_dir: str | os.PathLike, subset: str = "test", *, count: int | None = None, verify: bool = True
) -> list[GarmentTemplate]:
    """Load one subset ("train" / "test" / "outfits") of a split written by `make_split`: all its
    garments, or the first `count` (fewer when the subset is smaller).

    Raises:
        FileNotFoundError when the manifest is missing; ValueError when a garment asked for is not
        in the directory (a split generated in part) or on a checksum mismatch.
    """
    split_dir = Path(split_dir)
    if subset not in _SUBSETS:
        raise ValueError(f"subset must be one of {sorted(_SUBSETS)}, got {subset!r}")
    manifest = read_manifest(split_dir)
    if manifest is None:
        raise FileNotFoundError(
            f"{split_dir / 'manifest.json'} not found: generate the split first ({_GENERATE_HINT.format(dir=split_dir)})")
    size = int(manifest.get(f"num_{subset}", 0))
    wanted = size if count is None else min(count, size)
    rows = {r["index"]: r for r in manifest["garments"] if r["subset"] == subset}
    absent = [i for i in range(wanted) if i not in rows]
    if absent:
        raise ValueError(
            f"{split_dir} holds {sum(i in rows for i in range(wanted))} of the {wanted} {subset} garments asked for "
            f"(the split has {size}; first missing: index {absent[0]}): generate them ({_GENERATE_HINT.format(dir=split_dir)} "
            f"--num-train {manifest['num_train']} --num-test {manifest['num_test']} --seed {manifest['seed']}) "
            f"or load fewer (count)")
    out = []
    for i in range(wanted):
        row = rows[i]
        path = split_dir / row["file"]
        if verify and (not path.is_file() or sha256_file(path) != row["sha256"]):
            raise ValueError(f"{path}: missing, or its sha256 differs from the manifest (the file changed): "
                             f"generate the split again ({_GENERATE_HINT.format(dir=split_dir)}), which remakes it")
        v, f = read_ply(path)
        kind = OutfitParams if row["category"] == OUTFIT else GarmentParams
        out.append(GarmentTemplate(verts=v, faces=f, params=kind.from_dict(row["params"]),
                                   name=Path(row["file"]).stem, meta=dict(row)))
    return out


def load_or_generate(
    split_dir: str | os.PathLike, subset: str, *, count: int | None = None, seed: int = DEFAULT_SEED,
    workers: int | None = None, progress: bool = True,
) -> list[GarmentTemplate]:
    """The first `count` garments of `subset` (None: all), generating those missing first.

    A new directory becomes a split of the protocol's sizes (600 / 30, edge 1.5 cm) holding only
    the garments generated so far; an existing one keeps its manifest's sizes and edge length
    (its seed must be `seed`). The outfits have no fixed size: `count` of them (required) are made.
    """
    if subset == "outfits" and count is None:
        raise ValueError("say how many outfits to load (count): the split has no fixed number of them")
    manifest = read_manifest(split_dir)
    sizes = dict(num_train=DEFAULT_SIZES["train"], num_test=DEFAULT_SIZES["test"], target_edge=0.015)
    if manifest is not None:
        sizes = {k: manifest[k] for k in sizes}
    outfits = count if subset == "outfits" else 0
    make_split(split_dir, seed=seed, subset=subset, count=count, workers=workers, progress=progress,
               num_outfits=outfits, **sizes)
    return load_split(split_dir, subset, count=count)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description="Generate the seeded procedural garment split (only the garments "
                                 "missing from --out; an interrupted run resumes).")
    ap.add_argument("--out", required=True, help="output directory")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED)
    ap.add_argument("--num-train", type=int, default=DEFAULT_SIZES["train"])
    ap.add_argument("--num-test", type=int, default=DEFAULT_SIZES["test"])
    ap.add_argument("--num-outfits", type=int, default=0, help="procedural outfits (a top over trousers) to add")
    ap.add_argument("--target-edge", type=float, default=0.015, help="edge length [m]")
    ap.add_argument("--subset", choices=sorted(_SUBSETS), help="generate only this subset (default: both)")
    ap.add_argument("--count", type=int, help="generate only the first N garments of each subset (default: all)")
    ap.add_argument("--workers", type=int, default=None, help="processes (default: the machine's CPU count)")
    args = ap.parse_args(argv)
    m = make_split(args.out, seed=args.seed, num_train=args.num_train, num_test=args.num_test,
                   num_outfits=args.num_outfits, target_edge=args.target_edge, subset=args.subset, count=args.count,
                   workers=args.workers, progress=True)
    print(f"{Path(args.out) / 'manifest.json'} lists {len(m['garments'])} of the split's "
          f"{m['num_train'] + m['num_test'] + m['num_outfits']} garments")


if __name__ == "__main__":
    main()

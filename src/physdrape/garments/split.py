"""The fixed, seeded garment split: 600 training and 30 test procedural garments.

    python -m physdrape.garments.split --out DIR [--seed 0] [--num-train 600] [--num-test 30]

Writes DIR/train/NNNN_<category>.ply, DIR/test/NNNN_<category>.ply (binary PLY, float64,
deterministic bytes) and DIR/manifest.json (parameters, attempt, vertex/face counts, sha256).
Train and test draw from disjoint seed streams; categories cycle, so every category is in the
test set. Re-running with the same seed reproduces every file byte for byte (same machine and
library versions; see the manifest's `versions`).
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

#: Bumped whenever the generator's output changes; a split of another format is refused.
SPLIT_FORMAT = "physdrape-garment-split/2"  # 2: remeshing cleans short edges and slivers

from physdrape.garments.canonical import canonical_body
from physdrape.garments.generator import (
    COLLISION_MARGIN,
    GarmentTemplate,
    GarmentCategory,
    GarmentParams,
    generate_valid_garment,
)
from physdrape.garments.io import read_ply, sha256_file, write_ply

__all__ = ["make_split", "load_split", "split_entries", "DEFAULT_SEED"]

DEFAULT_SEED = 0
_SUBSETS = {"train": 1, "test": 2}


def split_entries(seed: int, num_train: int, num_test: int) -> list[dict]:
    """The (subset, index, category, garment seed) of every garment of a split."""
    cats = list(GarmentCategory)
    out = []
    for subset, n in (("train", num_train), ("test", num_test)):
        for i in range(n):
            gseed = int(np.random.SeedSequence([int(seed), _SUBSETS[subset], i]).generate_state(1)[0])
            out.append(dict(subset=subset, index=i, category=cats[i % len(cats)].value, seed=gseed))
    return out


def _make_one(args) -> dict:
    entry, out_dir, target_edge = args
    g, attempt = generate_valid_garment(entry["category"], entry["seed"], target_edge=target_edge)
    rel = f"{entry['subset']}/{entry['index']:04d}_{entry['category']}.ply"
    digest = write_ply(Path(out_dir) / rel, g.verts, g.faces)
    return dict(
        entry, file=rel, attempt=attempt, params=g.params.to_dict(), num_verts=g.num_verts,
        num_faces=g.num_faces, sha256=digest,
    )


def _versions() -> dict:
    import importlib.metadata as md

    out = {}
    for pkg in ("anny", "gpytoolbox", "warp-lang", "numpy", "scipy"):
        try:
            out[pkg] = md.version(pkg)
        except md.PackageNotFoundError:
            out[pkg] = None
    return out


def make_split(
    out_dir: str | os.PathLike,
    *,
    seed: int = DEFAULT_SEED,
    num_train: int = 600,
    num_test: int = 30,
    target_edge: float = 0.015,
    workers: int = 1,
    progress: bool = False,
) -> dict:
    """Generate (or regenerate) the split into `out_dir`; returns the manifest (also written).

    Args:
        out_dir: output directory (created).
        seed: split seed; the whole split is a pure function of it.
        num_train, num_test: subset sizes (the paper's protocol: 600 / 30).
        target_edge: garment edge length [m].
        workers: processes (each builds the body fields once; results do not depend on it).
    """
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    entries = split_entries(seed, num_train, num_test)
    jobs = [(e, str(out_dir), target_edge) for e in entries]
    if workers > 1:
        import multiprocessing as mp

        canonical_body()  # load the body once before forking
        with mp.get_context("fork").Pool(workers) as pool:
            rows = []
            for k, r in enumerate(pool.imap(_make_one, jobs, chunksize=4)):
                rows.append(r)
                if progress:
                    print(f"{k + 1}/{len(jobs)} {r['file']}", flush=True)
    else:
        rows = []
        for k, job in enumerate(jobs):
            rows.append(_make_one(job))
            if progress:
                print(f"{k + 1}/{len(jobs)} {rows[-1]['file']}", flush=True)
    manifest = dict(
        format=SPLIT_FORMAT,
        seed=int(seed),
        num_train=int(num_train),
        num_test=int(num_test),
        target_edge=float(target_edge),
        collision_margin=COLLISION_MARGIN,
        units="m, y-up, canonical Anny body (phenotypes 0.5, rest pose)",
        versions=_versions(),
        garments=rows,
    )
    text = json.dumps(manifest, indent=1, sort_keys=True) + "\n"
    tmp = out_dir / f".manifest.json.tmp{os.getpid()}"
    tmp.write_text(text)
    os.replace(tmp, out_dir / "manifest.json")
    return manifest


def load_split(
    split_dir: str | os.PathLike, subset: str = "test", *, verify: bool = True
) -> list[GarmentTemplate]:
    """Load one subset ("train" / "test") of a split written by `make_split`.

    Raises:
        FileNotFoundError when the manifest is missing; ValueError on a checksum mismatch.
    """
    split_dir = Path(split_dir)
    mpath = split_dir / "manifest.json"
    if not mpath.is_file():
        raise FileNotFoundError(
            f"{mpath} not found: generate the split first (python -m physdrape.garments.split --out {split_dir})"
        )
    if subset not in _SUBSETS:
        raise ValueError(f"subset must be one of {sorted(_SUBSETS)}, got {subset!r}")
    manifest = json.loads(mpath.read_text())
    if manifest.get("format") != SPLIT_FORMAT:
        raise ValueError(f"{mpath} is a split of format {manifest.get('format')!r}, this version reads "
                         f"{SPLIT_FORMAT!r}: regenerate it (python -m physdrape.garments.split --out DIR)")
    out = []
    for row in manifest["garments"]:
        if row["subset"] != subset:
            continue
        path = split_dir / row["file"]
        if verify and sha256_file(path) != row["sha256"]:
            raise ValueError(f"{path}: sha256 differs from the manifest; the file changed - regenerate the split")
        v, f = read_ply(path)
        out.append(GarmentTemplate(verts=v, faces=f, params=GarmentParams.from_dict(row["params"]),
                           name=Path(row["file"]).stem, meta=dict(row)))
    return out


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description="Generate the seeded procedural garment split.")
    ap.add_argument("--out", required=True, help="output directory")
    ap.add_argument("--seed", type=int, default=DEFAULT_SEED)
    ap.add_argument("--num-train", type=int, default=600)
    ap.add_argument("--num-test", type=int, default=30)
    ap.add_argument("--target-edge", type=float, default=0.015, help="edge length [m]")
    ap.add_argument("--workers", type=int, default=1)
    args = ap.parse_args(argv)
    m = make_split(args.out, seed=args.seed, num_train=args.num_train, num_test=args.num_test,
                   target_edge=args.target_edge, workers=args.workers, progress=True)
    print(f"wrote {len(m['garments'])} garments and {Path(args.out) / 'manifest.json'}")


if __name__ == "__main__":
    main()

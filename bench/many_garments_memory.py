"""A process's memory while it drapes many different garments: what a dataset-scale run holds.

    .venv/bin/python bench/many_garments_memory.py [--garments 400] [--every 25] [--base COMMIT]
        [--out results/many_garments_memory]

One `Draper` (the bundled model, T = 15, one torch thread) drapes `--garments` different generated
garments one after another (tshirt:0, longsleeve:1, tanktop:2, croptop:3, tshirt:4, …, each on the
default body and pose), as a manifest of that many garments does, and records the process's
resident memory (RSS) every `--every` garments. What a drape derives from a garment (its skinning
transfer, rest-state quantities, coarse space) is kept for the garments used most recently, so
that draping one again is cheap; the curve shows whether that keeping is bounded. With `--base`,
the same run of that commit's package (exported beside this one, as `bench/bench_drape.py` does)
runs at the same time in a second process; the two share the machine's two cores, so their
seconds are comparable with each other only. Writes <out>.md and <out>.json with the command and
the commit.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_drape import export_base
from report import page_head, write_report

ROOT = Path(__file__).resolve().parent.parent
CATEGORIES = ("tshirt", "longsleeve", "tanktop", "croptop")


def rss_mib() -> float:
    """This process's resident memory [MiB] (Linux)."""
    return int(Path("/proc/self/statm").read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def worker(package: str, garments: int, every: int) -> None:
    """Drape the garments with `package`'s Draper and print one JSON line per sample."""
    import importlib

    import torch

    torch.set_num_threads(1)
    api = importlib.import_module(f"{package}.api")
    draper = api.Draper()
    draper.drape("default")  # the model, the body and the kernels loaded before the first sample
    start = time.perf_counter()
    print(json.dumps({"garments": 0, "rss_mib": rss_mib(), "seconds": 0.0}), flush=True)
    for k in range(garments):
        draper.drape(f"{CATEGORIES[k % len(CATEGORIES)]}:{k}")
        if (k + 1) % every == 0 or k + 1 == garments:
            print(json.dumps({"garments": k + 1, "rss_mib": rss_mib(), "seconds": time.perf_counter() - start}),
                  flush=True)


def start_worker(path: Path, package: str, garments: int, every: int) -> subprocess.Popen:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(path), *filter(None, [os.environ.get("PYTHONPATH")])]),
               OMP_NUM_THREADS="1")
    return subprocess.Popen([sys.executable, __file__, "--worker", package, "--garments", str(garments),
                             "--every", str(every)], env=env, cwd=ROOT, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def samples(proc: subprocess.Popen, label: str) -> list[dict]:
    out, err = proc.communicate()
    if proc.returncode != 0:
        raise RuntimeError(f"the run of {label} failed:\n{err[-3000:]}")
    return [json.loads(line) for line in out.splitlines() if line.startswith("{")]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--garments", type=int, default=400)
    parser.add_argument("--every", type=int, default=25)
    parser.add_argument("--base", default=None, help="a commit whose run goes beside this one's")
    parser.add_argument("--out", default="results/many_garments_memory")
    parser.add_argument("--worker", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.garments < 1 or args.every < 1:
        parser.error("--garments and --every must be positive")
    if args.worker:
        worker(args.worker, args.garments, args.every)
        return
    command, prov, head = page_head("Memory while one process drapes many different garments")
    with tempfile.TemporaryDirectory() as tmp:
        runs = {"this commit": start_worker(ROOT / "src", "physdrape", args.garments, args.every)}
        if args.base:
            base = subprocess.run(["git", "rev-parse", "--short=10", args.base], cwd=ROOT, check=True,
                                  capture_output=True, text=True).stdout.strip()
            runs[f"base {base}"] = start_worker(export_base(args.base, Path(tmp)), "physdrape_base", args.garments,
                                                args.every)
        curves = {label: samples(proc, label) for label, proc in runs.items()}
    load = os.getloadavg()
    labels = list(curves)
    lines = [*head,
             f"One `Draper` (bundled model, T = 15, one torch thread) drapes {args.garments} different generated "
             f"garments in turn (categories cycling, seeds 0–{args.garments - 1}, default body and pose); resident "
             f"memory after the first drape of the default T-shirt (0) and every {args.every} garments. "
             + ("The runs went side by side, one process each; " if len(labels) > 1 else "")
             + f"load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.", "",
             "| garments draped | " + " | ".join(f"{label}: RSS [MiB] | growth [MiB per garment] | wall [s]"
                                                for label in labels) + " |",
             "|---:|" + "---:|---:|---:|" * len(labels)]
    for k, first in enumerate(curves[labels[0]]):
        cells = []
        for label in labels:
            row = curves[label][k]
            before = curves[label][k - 1] if k else None
            growth = ((row["rss_mib"] - before["rss_mib"]) / (row["garments"] - before["garments"])
                      if before else None)
            cells += [f"{row['rss_mib']:.0f}", "–" if growth is None else f"{growth:+.2f}", f"{row['seconds']:.0f}"]
        lines.append(f"| {first['garments']} | " + " | ".join(cells) + " |")
    write_report(args.out, lines, {"command": command, "provenance": prov, "garments": args.garments,
                                   "every": args.every, "load_average": list(load), "curves": curves})


if __name__ == "__main__":
    main()

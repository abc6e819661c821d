"""End-to-end drape timings through the public API, optionally side by side with an earlier commit.

    .venv/bin/python bench/bench_drape.py [--repeats 7] [--rounds 2] [--base COMMIT] [--cold]
        [--cold-garment SPEC] [--devices cpu cuda] [--compile] [--out results/bench_drape]

Rows (the bundled model, T = 15, one torch thread, medians):
- warm drape, same pose: `Draper.drape("default")` again in the same process (the default
  T-shirt on the default body and pose; skinning transfer fitted, body posed before);
- X_init: the drape's `init_s` phase of that call (skinning transfer, strain limiting, packing);
- warm drape, new pose: the same T-shirt on a pose the Draper has not posed yet (each pose drawn
  by the seeded sampler beforehand and passed as an array, so the sampler is not timed);
- batch of 8: one `drape` call of the T-shirt on 8 poses (the same 8 every call), per garment;
- new garment: a garment mesh the Draper has not draped before, on the default pose (a
  procedural T-shirt of a seed of its own per call, generated beforehand and passed as arrays, so
  the generator is not timed): the drape with the template's first-use work (skinning transfer
  fit, topology, coarse-space structure, closures), what each garment of a dataset costs;
- with `--cold`: a new process running `physdrape drape --out TMP` (imports, model and body
  load, transfer fit, drape, every output file); with `--cold-garment SPEC` that garment instead
  of the default (`--garment SPEC`, e.g. a generated `outfit:2`), each source run once untimed
  first, as a user's earlier call would have (what it keeps on disk, it keeps).

With `--base COMMIT` that commit's source runs in the same process as this commit's, exported
under another package name (`physdrape_base`: `git archive` of its `src/physdrape` with the package's
own imports renamed), and the two Drapers take turns call by call (the order swapped every
repeat), so that both see the same machine at the same moments: on a shared machine the speed
drifts by tens of percent over minutes, which separate processes turn into noise larger than
the change measured. The table gives both medians and the median of the per-call ratios. With
`--cold` the base's CLI runs as `python -m physdrape_base.cli` from the export. With `--compile`
this commit's Draper runs its network compiled (`Draper(compile_network=True)`; compiled by the
warm-up calls, outside the timing), the base's as the base runs it: `--base HEAD --compile` times
the compilation's gain alone.
Writes <out>.md and <out>.json with the command and the commit.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from timing import speedups

ROOT = Path(__file__).resolve().parents[1]
ROWS = {
    "same_pose": "warm drape, same pose [ms]",
    "x_init": "X_init (init phase of the same-pose drape) [ms]",
    "new_pose": "warm drape, new pose [ms]",
    "batch8": "batch of 8 poses, per garment [ms]",
    "new_garment": "warm drape, new garment [ms]",
}
#: The issue's targets [ms] (one thread, medians).
TARGETS = {"same_pose": 150.0, "x_init": 20.0, "new_pose": 250.0, "batch8": 100.0}


def worker(repeats: int, device: str, threads: int, packages: list[str],
           compile_network: bool = False) -> dict[str, dict[str, list[float]]]:
    """Time the rows in this process for each package (its source on sys.path), taking turns call
    by call, and return the samples [ms] per package."""
    import importlib

    import torch

    torch.set_num_threads(threads)
    drapers = {}
    for package in packages:
        api = importlib.import_module(f"{package}.api")
        options = {"compile_network": True} if compile_network and package == "physdrape" else {}
        drapers[package] = api.Draper(device=device, **options) if device != "cpu" else api.Draper(**options)
    for draper in drapers.values():
        draper.drape("default")  # fits and caches the skinning transfer, poses the default body
    first = drapers[packages[0]]
    poses = [first.poses(f"random:{1000 + k}")[0].pose[0] for k in range(repeats + 1)]
    eight = [first.poses(f"random:{k}")[0].pose[0] for k in range(8)]
    specs = importlib.import_module(f"{packages[0]}.api.specs")
    meshes = [(t.verts, t.faces) for t in (specs.garment_template(f"tshirt:{100 + k}") for k in range(repeats))]
    for draper in drapers.values():
        draper.drape("default", pose=poses[0])  # a first new pose outside the timing
        draper.drape("default", pose=eight, batch_size=8)
    out = {package: {key: [] for key in ROWS} for package in packages}
    for k in range(repeats):
        for package in packages if k % 2 == 0 else packages[::-1]:
            draper, row = drapers[package], out[package]
            t = time.perf_counter()
            [res] = draper.drape("default")
            row["same_pose"].append(1e3 * (time.perf_counter() - t))
            row["x_init"].append(1e3 * res.timings["init_s"])
            t = time.perf_counter()
            draper.drape("default", pose=poses[k + 1])
            row["new_pose"].append(1e3 * (time.perf_counter() - t))
            if k < max(2, repeats // 2):
                t = time.perf_counter()
                draper.drape("default", pose=eight, batch_size=8)
                row["batch8"].append(1e3 * (time.perf_counter() - t) / 8)
            t = time.perf_counter()
            draper.drape(meshes[k])
            row["new_garment"].append(1e3 * (time.perf_counter() - t))
    return out


def export_base(commit: str, dest: Path) -> Path:
    """`src/physdrape` of `commit` as the package `physdrape_base` under `dest` (its own imports
    and resource lookups renamed), so that it can be imported beside this commit's `physdrape`."""
    archive = subprocess.run(["git", "archive", commit, "src/physdrape"], cwd=ROOT, check=True, capture_output=True)
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)
    package = dest / "physdrape_base"
    (dest / "src" / "physdrape").rename(package)
    pattern = re.compile(r'(\bfrom physdrape)([ .])|(^\s*import physdrape)\b|(files\("physdrape)"\)', re.MULTILINE)
    for path in package.rglob("*.py"):
        text = path.read_text()
        path.write_text(pattern.sub(lambda m: (m.group(1) + "_base" + m.group(2)) if m.group(1)
                                    else (m.group(3) + "_base") if m.group(3) else m.group(4) + '_base")', text))
    return dest


def _python_path(*paths: Path) -> str:
    """PYTHONPATH for a worker: the sources timed first, then the caller's own entries (where
    dependencies installed outside site-packages live)."""
    return os.pathsep.join([*(str(p) for p in paths), *filter(None, [os.environ.get("PYTHONPATH")])])


def _run_worker(paths: list[Path], packages: list[str], repeats: int, device: str,
                threads: int, compile_network: bool) -> dict[str, dict[str, list[float]]]:
    env = dict(os.environ, PYTHONPATH=_python_path(*paths), OMP_NUM_THREADS=str(threads))
    proc = subprocess.run([sys.executable, __file__, "--worker", "--repeats", str(repeats), "--device", device,
                           "--threads", str(threads), "--packages", *packages,
                           *(["--compile"] if compile_network else [])], env=env, capture_output=True,
                          text=True, cwd=ROOT, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"the timing process for {packages} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _cold_cli(src: Path, package: str, repeats: int, threads: int, garment: str) -> list[float]:
    env = dict(os.environ, PYTHONPATH=_python_path(src), OMP_NUM_THREADS=str(threads))
    times = []
    with tempfile.TemporaryDirectory() as tmp:
        for k in range(repeats):
            t = time.perf_counter()
            subprocess.run([sys.executable, "-m", f"{package}.cli", "drape", "--out", f"{tmp}/o{k}", "--threads",
                            str(threads), *(["--garment", garment] if garment != "default" else [])], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=env, cwd=ROOT)
            times.append(1e3 * (time.perf_counter() - t))
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7, help="timed calls per row and process")
    parser.add_argument("--rounds", type=int, default=2, help="processes per source, alternating")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--base", default=None, help="an earlier commit to time side by side")
    parser.add_argument("--devices", nargs="+", default=["cpu"], help="cpu and/or cuda (this commit only)")
    parser.add_argument("--cold", action="store_true", help="also time a cold `physdrape drape` (new process)")
    parser.add_argument("--cold-garment", default="default", help="the garment spec of the cold run (with --cold)")
    parser.add_argument("--compile", action="store_true", help="this commit's network compiled (torch.compile)")
    parser.add_argument("--out", default="results/bench_drape")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument("--device", default="cpu", help=argparse.SUPPRESS)
    parser.add_argument("--packages", nargs="+", default=["physdrape"], help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.repeats, args.device, args.threads, args.packages, args.compile)))
        return

    import torch
    from report import source_lines, write_report

    from physdrape.provenance import provenance

    devices = [d for d in args.devices if d == "cpu" or torch.cuda.is_available()]
    skipped = [d for d in args.devices if d not in devices]
    this = "this commit, compiled network" if args.compile else "this commit"
    if args.base:  # a name (HEAD, a branch) as the commit it names, which the file records
        args.base = subprocess.run(["git", "rev-parse", "--verify", f"{args.base}^{{commit}}"], cwd=ROOT, check=True,
                                   capture_output=True, text=True).stdout.strip()
    base = f"base {args.base[:10]}" if args.base else None
    samples: dict[str, dict[str, list[float]]] = {}
    ratios: dict[str, list[float]] = {}
    load = []
    with tempfile.TemporaryDirectory(prefix="physdrape-base-") as tmp:
        base_dir = export_base(args.base, Path(tmp)) if args.base else None
        if args.cold and args.cold_garment != "default":  # untimed: what a user's earlier call kept on disk
            _cold_cli(ROOT / "src", "physdrape", 1, args.threads, args.cold_garment)
            if base_dir is not None:
                _cold_cli(base_dir, "physdrape_base", 1, args.threads, args.cold_garment)
        for _ in range(args.rounds):
            for device in devices:
                paired = base_dir is not None and device == "cpu"
                packages = ["physdrape", "physdrape_base"] if paired else ["physdrape"]
                got = _run_worker([ROOT / "src", *([base_dir] if paired else [])], packages, args.repeats, device,
                                  args.threads, args.compile)
                load.append(os.getloadavg()[0])
                for package, name in zip(packages, [this, base]):
                    for row, values in got[package].items():
                        samples.setdefault(f"{name} ({device})", {}).setdefault(row, []).extend(values)
                if paired:
                    for row in got["physdrape"]:
                        ratios.setdefault(row, []).extend(speedups(got["physdrape"][row], got["physdrape_base"][row]))
            if args.cold:
                samples.setdefault(f"{this} (cpu)", {}).setdefault("cold_cli", []).extend(
                    _cold_cli(ROOT / "src", "physdrape", 1, args.threads, args.cold_garment))
                if base_dir is not None:
                    samples.setdefault(f"{base} (cpu)", {}).setdefault("cold_cli", []).extend(
                        _cold_cli(base_dir, "physdrape_base", 1, args.threads, args.cold_garment))
                    ratios.setdefault("cold_cli", []).extend(speedups(samples[f"{this} (cpu)"]["cold_cli"][-1:],
                                                                      samples[f"{base} (cpu)"]["cold_cli"][-1:]))
    cold = "physdrape drape" + (f" --garment {args.cold_garment}" if args.cold_garment != "default" else "")
    rows = dict(ROWS, **({"cold_cli": f"cold `{cold}` (new process, all outputs) [ms]"} if args.cold else {}))
    medians = {key: {row: statistics.median(v) for row, v in got.items()} for key, got in samples.items()}
    columns = list(medians)
    command = shlex.join(["python", *sys.argv])
    record = {"command": command, "provenance": provenance(), "threads": args.threads, "repeats": args.repeats,
              "rounds": args.rounds, "load_average_during": load, "load_average_end": os.getloadavg(),
              "devices_skipped": skipped, "targets_ms": TARGETS, "samples_ms": samples, "medians_ms": medians,
              "paired_ratios_base_over_this": ratios}
    head = ["| row | " + " | ".join(columns) + (" | base / this (median of paired calls) |" if args.base else " |")
            + " target |",
            "|---|" + "---:|" * len(columns) + ("---:|" if args.base else "") + "---:|"]
    lines = ["# Drape timings through the public API (bundled model, T = 15)", "",
             *source_lines(command, record["provenance"]),
             f"{args.threads} torch thread(s); medians over {args.rounds} process(es) × {args.repeats} calls"
             + (" (this commit and the base taking turns call by call in each)" if args.base else "")
             + "; load average (1 min) during the run "
             + ", ".join(f"{v:.2f}" for v in load) + (f"; not available here: {', '.join(skipped)}" if skipped else ""),
             "", *head]
    for row, label in rows.items():
        values = [medians[c].get(row) for c in columns]
        cells = " | ".join("–" if v is None else f"{v:.0f}" for v in values)
        ratio = ""
        if args.base:
            ratio = f" {statistics.median(ratios[row]):.2f} |" if ratios.get(row) else " – |"
        target = f"≤ {TARGETS[row]:.0f}" if row in TARGETS else "–"
        lines.append(f"| {label} | {cells} |{ratio} {target} |")
    write_report(args.out, lines, record)


if __name__ == "__main__":
    main()

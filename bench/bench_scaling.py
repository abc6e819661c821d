"""Scaling of a drape: cost per garment against garment size, and garments per second against batch size and threads.

Everything runs through the public API (`physdrape.api.Draper.drape`), each size and each batch
size in a fresh subprocess of this script (`--worker`), so that its peak memory
(`resource.getrusage(RUSAGE_SELF).ru_maxrss`) is its own:

- **sizes**: the bundled T-shirt (`assets/garments/tshirt_default.ply`, 3k vertices) remeshed
  (`physdrape.garments.remesh`, isotropic, boundary loops kept) to about `--sizes` vertices
  (default 1k, 4k, 16k, 64k; the target edge length is corrected until the count is within 5 %),
  draped alone (batch 1) on `--size-threads` threads at T = `--steps`, in the default pose, the
  same posed body every call (the Draper keeps it: the garment's cost, not the body's). Per size:
  ms per garment (wall time of `Draper.drape`, median of `--repeats` calls after a warm-up; the
  sizes of at least `--large-from` vertices `--large-repeats` calls), µs per vertex and its
  ratio to the size nearest 4k; and per phase (medians): posing the body (`body_s`), X_init
  (`init_s`: skinning transfer, strain limiting, batch build), the model's graph features, GNN,
  stretching solver and collision handler (timed by forward hooks on the model's modules), and
  the metrics of the result (`metrics_s`). The remeshed garments are cached in `--cache-dir`.
- **batches**: the bundled T-shirt on n = `--batches` (default 1, 8, 32) poses at once
  (`Draper.drape(garment, pose=[...n poses], batch_size=n)`), on each of `--threads` (default 1
  and 2), the thread counts alternating call by call in one process per batch size (the
  machine's drift over a run, which on a shared machine exceeds the effect of a second thread,
  then weighs on each count alike): garments per second and ms per garment (median of
  `--repeats` calls per count after a warm-up round), and the ratio of 2 threads over 1. On the
  CPU a batch of several poses drapes as groups (`api.batch_threads`: one per thread side by
  side, and packs of at most `CPU_PACK_VERTICES` vertices); its phases are the groups' summed,
  over n. `--batch-poses fresh` (the default) drapes n new poses each
  call (drawn beforehand with the API's `random:SEED` sampler and passed as arrays, so the
  posing, arm check and body surfaces are paid as a dataset pays them); `same` repeats one set of n
  poses (posed bodies kept).

Writes `<out>/bench_scaling.json` (every configuration's numbers) and `<out>/bench_scaling.md`
(the two tables), each naming the command, the git commit, the load average, the torch threads
and the date.

    .venv/bin/python bench/bench_scaling.py                 # the full run
    .venv/bin/python bench/bench_scaling.py --quick --out /tmp/scaling   # 1k/4k, batches 1 and 4
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import resource
import shlex
import statistics
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve()
DEFAULT_GARMENT = HERE.parents[1] / "src" / "physdrape" / "assets" / "garments" / "tshirt_default.ply"
#: The model's modules timed by forward hooks, in call order (features: from the model's call to the GNN's).
HOOKED = ("gnn", "solver", "handler")


def log(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def parse_ints(text: str) -> list[int]:
    """ "1,8,32" or "1k,4k" → [1, 8, 32] / [1000, 4000]."""
    out = []
    for part in text.split(","):
        part = part.strip().lower()
        out.append(int(float(part[:-1]) * 1000) if part.endswith("k") else int(part))
    if not out or min(out) < 1:
        raise argparse.ArgumentTypeError(f"expected positive integers, got {text!r}")
    return out


# ------------------------------------------------------------------------------------------
# Garments of a given size
# ------------------------------------------------------------------------------------------


def remeshed_garment(target: int, cache_dir: Path, source: Path = DEFAULT_GARMENT, *, tries: int = 6,
                     invalid_tries: int = 2) -> tuple[Path, str]:
    """(a .ply of `source` at about `target` vertices, how it was made), cached in `cache_dir` by
    source and target. The garment passes the Draper's check of garment files (`validate_garment`
    as `physdrape.api.specs` runs it: no self-intersections, at most 5 % of its area inside the
    canonical body). Made by isotropic remeshing to within 5 % of `target`, the edge length
    corrected from each result's count; where `invalid_tries` results within 5 % fail the check
    (remeshing fine enough to resolve the T-shirt's narrow gaps, e.g. at 3 mm edges, makes
    crossing faces there), by a flat 1-to-4 midpoint subdivision of the garment of `target` / 4
    vertices, which keeps every face in its parent's plane and so adds no crossing."""
    import trimesh

    from physdrape.garments import validate_garment
    from physdrape.garments.remesh import mean_edge_length, remesh

    path = cache_dir / f"{source.stem}_{target}.ply"
    how_path = path.with_suffix(".txt")
    if path.is_file() and how_path.is_file():
        return path, how_path.read_text().strip()

    def check(v, f) -> list[str]:
        return validate_garment(v, f, name=path.name, require_clearance=False, max_inside_area_fraction=0.05).errors

    def keep(v, f, how: str) -> tuple[Path, str]:
        cache_dir.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.ply")
        trimesh.Trimesh(v, f, process=False).export(tmp)
        os.replace(tmp, path)
        how_path.write_text(how + "\n")
        return path, how

    mesh = trimesh.load(source, process=False)
    verts, faces = np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64)
    edge = mean_edge_length(verts, faces) * (len(verts) / target) ** 0.5
    invalid = 0
    for _ in range(tries):
        t0 = time.perf_counter()
        rv, rf = remesh(verts, faces, target_edge=edge)
        close = abs(len(rv) - target) <= 0.05 * target
        errors = check(rv, rf) if close else []
        log(f"  remeshed {source.name} at edge {1e3 * edge:.3f} mm: {len(rv)} vertices "
            f"({time.perf_counter() - t0:.1f} s){'; invalid: ' + '; '.join(errors) if errors else ''}")
        if close and not errors:
            return keep(rv, rf, f"remesh (edge {1e3 * edge:.3f} mm)")
        invalid += bool(errors)
        if invalid >= invalid_tries:
            break
        edge *= 1.01 if close else (len(rv) / target) ** 0.5  # vertex count ∝ area / edge²
    if target < 4 * len(verts):
        raise RuntimeError(f"no valid remesh of {source} within 5 % of {target} vertices")
    coarse, how = remeshed_garment(target // 4, cache_dir, source, tries=tries, invalid_tries=invalid_tries)
    mesh = trimesh.load(coarse, process=False)
    sv, sf = trimesh.remesh.subdivide(np.asarray(mesh.vertices, np.float64), np.asarray(mesh.faces, np.int64))
    errors = check(sv, sf)
    if errors:
        raise RuntimeError(f"the subdivision of {coarse} fails the garment check: {'; '.join(errors)}")
    log(f"  subdivided {coarse.name}: {len(sv)} vertices")
    return keep(sv, sf, f"{how}, then subdivided 1-to-4 at edge midpoints")


# ------------------------------------------------------------------------------------------
# One configuration (run in its own process)
# ------------------------------------------------------------------------------------------


class PhaseTimer:
    """Wall seconds of the model's phases per call, from forward hooks on the model and its
    `HOOKED` modules: features (model call → GNN call), gnn, solver, handler."""

    def __init__(self, model) -> None:
        self.marks: dict[str, float] = {}
        model.register_forward_pre_hook(lambda *_: self._mark("model0"))
        for name in HOOKED:
            module = getattr(model, name)
            module.register_forward_pre_hook(lambda *_, n=name: self._mark(f"{n}0"))
            module.register_forward_hook(lambda *_, n=name: self._mark(f"{n}1"))

    def _mark(self, key: str) -> None:
        self.marks[key] = time.perf_counter()

    def phases(self) -> dict[str, float]:
        m, self.marks = self.marks, {}
        out = {"features_s": m["gnn0"] - m["model0"]} if "gnn0" in m and "model0" in m else {}
        out.update({f"{n}_s": m[f"{n}1"] - m[f"{n}0"] for n in HOOKED if f"{n}0" in m})
        return out


def _rss_gib() -> float:
    """Peak resident memory of this process so far [GiB] (Linux: ru_maxrss in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def _gpu_gib(device) -> float | None:
    """Peak GPU memory allocated by torch in this process [GiB] on a CUDA device, else None."""
    import torch

    return torch.cuda.max_memory_allocated(device) / 2**30 if device.type == "cuda" else None


def _peak(r: dict) -> str:
    """A row's peak memory cell: RSS [GiB], and the GPU's beside it on a GPU."""
    gpu = r.get("peak_gpu_gib")
    return f"{r['peak_rss_gib']:.2f}" + ("" if gpu is None else f" (GPU {gpu:.2f})")


def _group_phases(results) -> dict[str, float]:
    """A batch's phase times [s] summed over the groups it draped in (each result's timings are its
    group's: over the group's size per result, summed over the results)."""
    keys = [k for k in results[0].timings if k.endswith("_s")]
    return {k: sum(r.timings[k] / r.timings["batch_size"] for r in results) for k in keys}


def worker(spec: dict) -> dict:
    """Drape one configuration: `spec` = {garment, batch, threads, steps, repeats, poses}."""
    import torch

    torch.set_num_threads(spec["threads"])
    from physdrape.api import Draper

    t0 = time.perf_counter()
    draper = Draper(steps=spec["steps"], device=spec.get("device", "cpu"))
    template = draper.garment(spec["garment"])
    draper.body("anny")
    timer = PhaseTimer(draper.model)
    n, repeats = spec["batch"], spec["repeats"]
    if spec["poses"] == "default":
        pose_sets = [None] * (repeats + 1)
    else:  # n poses per call, drawn beforehand (arrays: posing and the arm check stay in the timed drape)
        calls = 1 if spec["poses"] == "same" else repeats + 1
        drawn = [[draper.poses(f"random:{spec['pose_seed'] + c * n + i}")[0].pose[0].numpy() for i in range(n)]
                 for c in range(calls)]
        pose_sets = drawn * (repeats + 1) if calls == 1 else drawn
    setup_s = time.perf_counter() - t0
    rss_setup = _rss_gib()
    records = []
    for call, poses in enumerate(pose_sets):  # call 0: the warm-up (transfer fit, kernels, caches)
        t = time.perf_counter()
        results = draper.drape(template, pose=poses, batch_size=n)
        wall = time.perf_counter() - t
        record = {"wall_s": wall, **{k: v for k, v in results[0].timings.items() if k.endswith("_s")},
                  **timer.phases()}
        record["b2g_percent"] = float(np.mean([r.metrics["b2g_percent"] for r in results]))
        records.append(record)
        if len(results) != n:
            raise RuntimeError(f"{len(results)} results for a batch of {n}")
    timed = records[1:]
    medians = {key: statistics.median(r[key] for r in timed) for key in timed[0]}
    return {**spec, "num_verts": template.num_verts, "num_faces": len(template.faces),
            "torch_threads": torch.get_num_threads(), "setup_s": setup_s, "warmup_wall_s": records[0]["wall_s"],
            "median": medians, "calls": timed, "peak_rss_gib": _rss_gib(), "setup_peak_rss_gib": rss_setup,
            "peak_gpu_gib": _gpu_gib(draper.device)}


def batch_worker(spec: dict) -> list[dict]:
    """Drape a batch of `spec["batch"]` garments on each torch thread count of `spec["threads"]`,
    the counts alternating call by call in one process (rounds of one call per count, the order
    reversed every other round), so that the machine's drift over a run weighs on each alike:
    one row per count, `spec["repeats"]` timed rounds after a warm-up round."""
    import torch

    from physdrape.api import Draper

    counts, n, repeats = spec["threads"], spec["batch"], spec["repeats"]
    t0 = time.perf_counter()
    draper = Draper(steps=spec["steps"], device=spec.get("device", "cpu"))
    template = draper.garment(spec["garment"])
    draper.body("anny")
    timer = PhaseTimer(draper.model)
    calls = 1 if spec["poses"] == "same" else (repeats + 1) * len(counts)
    drawn = [[draper.poses(f"random:{spec['pose_seed'] + c * n + i}")[0].pose[0].numpy() for i in range(n)]
             for c in range(calls)]
    setup_s = time.perf_counter() - t0
    records: dict[int, list[dict]] = {t: [] for t in counts}
    call = 0
    for round_ in range(repeats + 1):  # round 0: the warm-up (transfer fit, kernels, caches)
        for threads in counts if round_ % 2 == 0 else counts[::-1]:
            torch.set_num_threads(threads)
            t = time.perf_counter()
            results = draper.drape(template, pose=drawn[call % len(drawn)], batch_size=n)
            wall = time.perf_counter() - t
            call += 1
            if len(results) != n:
                raise RuntimeError(f"{len(results)} results for a batch of {n}")
            record = {"wall_s": wall, **_group_phases(results),
                      **timer.phases(), "b2g_percent": float(np.mean([r.metrics["b2g_percent"] for r in results]))}
            if round_:
                records[threads].append(record)
    rows = []
    for threads, timed in records.items():
        medians = {key: statistics.median(r[key] for r in timed) for key in timed[0]}
        rows.append({**spec, "threads": threads, "torch_threads": threads, "num_verts": template.num_verts,
                     "num_faces": len(template.faces), "setup_s": setup_s, "median": medians, "calls": timed,
                     "peak_rss_gib": _rss_gib(), "peak_gpu_gib": _gpu_gib(draper.device)})
    return rows


def run_worker(spec: dict, timeout: float) -> dict | list[dict]:
    """`worker(spec)` (`batch_worker` for a batch spec) in a fresh process of this script; its
    result (or an "error")."""
    cmd = [sys.executable, str(HERE), "--worker", json.dumps(spec)]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, check=False)
    except subprocess.TimeoutExpired:
        return {**spec, "error": f"timed out after {timeout:g} s"}
    if proc.returncode != 0:
        tail = "\n".join(proc.stderr.strip().splitlines()[-5:])
        return {**spec, "error": f"exit {proc.returncode}: {tail}"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


# ------------------------------------------------------------------------------------------
# Tables
# ------------------------------------------------------------------------------------------


def run_header() -> dict:
    """Where and how the numbers were made: command, commit, load, date."""
    from physdrape.provenance import provenance

    prov = provenance()
    return {"command": " ".join(shlex.quote(a) for a in [".venv/bin/python", *sys.argv]),
            "git_commit": prov["git_commit"], "git_dirty": prov["git_dirty"],
            "date_utc": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%d %H:%M UTC"),
            "load_average_start": list(os.getloadavg()), "cpu_count": os.cpu_count(), "versions": prov}


def size_table(rows: list[dict]) -> list[str]:
    ok = [r for r in rows if "error" not in r]
    if not ok:
        return ["(no size configuration ran)"]
    base = min(ok, key=lambda r: abs(r["num_verts"] - 4000))
    base_us = 1e6 * base["median"]["wall_s"] / base["num_verts"]
    phases = ("body_s", "init_s", "features_s", "gnn_s", "solver_s", "handler_s", "metrics_s")
    lines = [(f"| target | verts | faces | ms / garment | µs / vertex | / {base['num_verts']}-vertex µs/vertex "
             "| body | X_init | features | GNN | solver | handler | metrics [ms] | repeats | peak RSS [GiB] |"),
             "|---" * 15 + "|"]
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['target']} | – | – | failed: {r['error'][:200]} |" + " |" * 11)
            continue
        med = r["median"]
        us = 1e6 * med["wall_s"] / r["num_verts"]
        cells = " | ".join(f"{1e3 * med[p]:.1f}" if p in med else "–" for p in phases)
        lines.append(f"| {r['target']} | {r['num_verts']} | {r['num_faces']} | {1e3 * med['wall_s']:.1f} | {us:.1f} "
                     f"| {us / base_us:.2f} | {cells} | {r['repeats']} | {_peak(r)} |")
    lines += ["", "The garments: " + "; ".join(f"{r['target']}: {r['made_by']}" for r in rows) + "."]
    return lines


def batch_table(rows: list[dict]) -> list[str]:
    lines = [("| batch | threads | s / call | garments / s | ms / garment | garments/s: 2 threads / 1 "
             "| body | X_init | model | metrics [ms / garment] | peak RSS [GiB] |"), "|---" * 11 + "|"]
    rate = {(r["batch"], r["torch_threads"]): r["batch"] / r["median"]["wall_s"] for r in rows if "error" not in r}
    for r in rows:
        if "error" in r:
            lines.append(f"| {r['batch']} | {r['threads']} | failed: {r['error'][:200]} |" + " |" * 8)
            continue
        med, n = r["median"], r["batch"]
        one = rate.get((n, 1))
        ratio = f"{rate[(n, r['torch_threads'])] / one:.2f}" if one and r["torch_threads"] != 1 else "–"
        per = " | ".join(f"{1e3 * med[p] / n:.1f}" for p in ("body_s", "init_s", "model_s", "metrics_s"))
        lines.append(f"| {n} | {r['torch_threads']} | {med['wall_s']:.3g} | {n / med['wall_s']:.2f} "
                     f"| {1e3 * med['wall_s'] / n:.1f} | {ratio} | {per} | {_peak(r)} |")
    return lines


def write_markdown(path: Path, header: dict, args, sizes: list[dict], batches: list[dict]) -> None:
    load = " / ".join(f"{v:.2f}" for v in header["load_average_start"])
    load_end = " / ".join(f"{v:.2f}" for v in header["load_average_end"])
    lines = ["# Scaling: cost per garment against size, throughput against batch size and threads", "",
             f"Command: `{header['command']}`  ",
             (f"Commit {header['git_commit']}{' (dirty tree)' if header['git_dirty'] else ''}; {header['date_utc']}; "
             f"{header['cpu_count']} CPUs; load average {load} (1/5/15 min) at the start, {load_end} at the end. "
             f"Each size in its own process, each batch size in its own process with its thread counts "
             f"alternating call by call (side by side); `Draper.drape` at T = {args.steps}, medians of timed "
             f"calls after a warm-up call; device {args.device}"
             + ("" if args.device == "cpu" else " (the phases are host-side times: the GPU runs asynchronously "
                "and synchronises where the drape reads a result back; the wall time includes all of it)")
             + "."), "",
             f"## Cost per garment against size ({args.size_threads} torch thread(s), batch 1, the same posed body)",
             "", ("The bundled T-shirt remeshed to each target; ms / garment is the wall time of `Draper.drape`; "
             "the phases are its `DrapeResult.timings` (body, X_init, metrics) and the model's modules "
             "(features, GNN, solver, handler; forward hooks). µs / vertex is ms / garment over the vertices."), "",
             *size_table(sizes), "",
             (f"## Throughput against batch size and threads (the bundled T-shirt on n poses, "
             f"{args.batch_poses} poses every call)"), "",
             ("garments / s = n / (wall time of one `Draper.drape` call of n garments, batch_size = n); the "
             "phases per garment are `DrapeResult.timings` summed over the groups the batch drapes in, over n "
             "(on the CPU a batch drapes as groups: one per thread side by side, and packs of at most "
             "`api.batch_threads.CPU_PACK_VERTICES` vertices; on 2 threads the groups' phases overlap, so they "
             "add up to more than the wall time); the peak RSS is that of the batch size's process, over all "
             "its thread counts."), "", *batch_table(batches), ""]
    path.write_text("\n".join(lines))


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--sizes", type=parse_ints, default=parse_ints("1k,4k,16k,64k"),
                        help="garment sizes [vertices] (the T-shirt remeshed)")
    parser.add_argument("--size-threads", type=int, default=1, help="torch threads of the size runs")
    parser.add_argument("--batches", type=parse_ints, default=parse_ints("1,8,32"), help="batch sizes")
    parser.add_argument("--threads", type=parse_ints, default=parse_ints("1,2"), help="torch threads of the batch runs")
    parser.add_argument("--batch-poses", choices=("fresh", "same"), default="fresh",
                        help="batch runs: new poses every call, or one set of poses repeated")
    parser.add_argument("--steps", type=int, default=15, help="solver steps T")
    parser.add_argument("--device", choices=("cpu", "cuda"), default="cpu", help="where the drapes run")
    parser.add_argument("--repeats", type=int, default=5, help="timed calls per configuration (median)")
    parser.add_argument("--large-from", type=int, default=32000, help="sizes of at least this many vertices ...")
    parser.add_argument("--large-repeats", type=int, default=2, help="... are timed this many times")
    parser.add_argument("--pose-seed", type=int, default=0, help="first seed of the random poses")
    parser.add_argument("--timeout", type=float, default=3600.0, help="per configuration [s]")
    parser.add_argument("--cache-dir", default=str(Path.home() / ".cache" / "physdrape" / "bench_scaling"),
                        help="where the remeshed garments are kept")
    parser.add_argument("--quick", action="store_true",
                        help="a smoke run: sizes 1k and 4k, batches 1 and 4 on 1 and 2 threads, 1 repeat")
    parser.add_argument("--out", default="results", help="folder of bench_scaling.{json,md}")
    parser.add_argument("--worker", help=argparse.SUPPRESS)  # internal: one configuration, JSON
    args = parser.parse_args(argv)
    if args.worker:
        spec = json.loads(args.worker)
        print(json.dumps(batch_worker(spec) if spec["kind"] == "batch" else worker(spec)))
        return 0
    if args.quick:
        args.sizes, args.batches, args.repeats = [1000, 4000], [1, 4], 1

    header = run_header()
    t_start = time.perf_counter()
    sizes = []
    for target in args.sizes:
        garment, how = remeshed_garment(target, Path(args.cache_dir).expanduser())
        repeats = args.large_repeats if target >= args.large_from else args.repeats
        spec = {"kind": "size", "target": target, "garment": str(garment), "made_by": how, "batch": 1,
                "threads": args.size_threads, "device": args.device,
                "steps": args.steps, "repeats": repeats, "poses": "default", "pose_seed": args.pose_seed}
        log(f"size {target}: {garment.name}, {repeats} repeat(s)")
        sizes.append(run_worker(spec, args.timeout))
        log(f"  {json.dumps({k: sizes[-1].get(k) for k in ('num_verts', 'median', 'peak_rss_gib', 'error')})}")
    batches = []
    for n in args.batches:
        spec = {"kind": "batch", "garment": str(DEFAULT_GARMENT), "batch": n, "threads": args.threads, "device": args.device,
                "steps": args.steps, "repeats": args.repeats, "poses": args.batch_poses, "pose_seed": args.pose_seed}
        log(f"batch {n}, {args.threads} thread(s) alternating")
        rows = run_worker(spec, args.timeout)
        rows = [{**spec, "threads": t, "error": rows["error"]} for t in args.threads] if "error" in rows else rows
        batches += rows
        for r in rows:
            log(f"  error: {r['error']}" if "error" in r else
                f"  {r['threads']} thread(s): {n / r['median']['wall_s']:.2f} garments/s")
    header["load_average_end"] = list(os.getloadavg())
    header["total_wall_s"] = time.perf_counter() - t_start

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    config = {k: v for k, v in vars(args).items() if k != "worker"}
    payload = {"format": "physdrape-bench-scaling-1", **header, "config": config, "sizes": sizes, "batches": batches}
    (out / "bench_scaling.json").write_text(json.dumps(payload, indent=1) + "\n")
    write_markdown(out / "bench_scaling.md", header, args, sizes, batches)
    log(f"wrote {out}/bench_scaling.{{json,md}} in {header['total_wall_s']:.0f} s")
    print((out / "bench_scaling.md").read_text())
    return 0 if all("error" not in r for r in sizes + batches) else 1


if __name__ == "__main__":
    sys.exit(main())

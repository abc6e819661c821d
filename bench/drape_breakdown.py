"""Where a warm drape's time goes: the phases of `Draper.drape` of the default T-shirt, timed inside.

    .venv/bin/python bench/drape_breakdown.py [--repeats 9] [--device cpu|cuda] [--out results/drape_breakdown]

The bundled model at T = 15 on one torch thread, as `bench/bench_drape.py` times it end to end:
the same pose again (the body posed and its surface built before), a new pose per call (drawn
by the seeded sampler beforehand and passed as an array), and a batch of 8 poses (the same 8 at
every call, as in `bench_drape.py`; its times and calls per garment). This script wraps the methods that make
up a drape with timers (the product code is not changed) and reports per drape the median time
spent in each, with how often it ran:

- posing the body, and within it the check of the arms against the torso (which builds a BVH of
  the torso of its own);
- the init phase (the drape's `init_s`: the pipeline's build), and within it the build of the
  body surface (its BVH), the doubtful faces of a new body (`BodySurface.doubtful_faces`) and
  X_init (skinning transfer and strain limiting, its queries included);
- the graph inputs and the GNN;
- the stretching solver, and within it the body requeries, the coarse factorisations, each
  step's forces with the stiffness and contact blocks and their inverses (one launch and its
  inversion, `Relaxation.step_terms`), the coarse solves, the stiffness products of the first
  steps' inner iterations and the line-search potentials (the rest: the conjugation, clips and
  updates);
- the collision handler and the metrics (the drape's `metrics_s`);
- across all of them, the time inside Warp kernels (compiled code), and of that the BVH searches
  (closest faces, winding numbers, rays): what a faster Python or torch layer cannot remove.

Indented rows are part of the unindented row above them. With `--device cuda` the drape runs on
the GPU and every timed call synchronises the GPU before and after it (the GPU's work is counted
in the phase that launched it, plus a few microseconds per call); the Warp rows count CPU kernels
only, so they are empty there. Writes <out>.md and <out>.json with the command, the commit and
the load average.
"""

from __future__ import annotations

import argparse
import collections
import os
import shlex
import statistics
import sys
import time

#: (label, module, class or None, attribute, indent): the timed methods, in the table's order.
PHASES = [
    ("posing", "physdrape.api.draper", "Draper", "_posed_bodies", 0),
    ("arm–torso check", "physdrape.api.draper", None, "arm_torso_penetration", 1),
    ("body surface build", "physdrape.pipeline", "PosedBodies", "surface", 1),
    ("doubtful faces", "physdrape.geometry.proximity", "BodySurface", "doubtful_faces", 1),
    ("X_init", "physdrape.pipeline", "DrapePipeline", "_x_inits", 1),
    ("graph inputs", "physdrape.model.physdrape", "PhysDrape", "_graph_inputs", 0),
    ("GNN", "physdrape.model.gnn", "EncodeProcessDecode", "forward", 0),
    ("stretching solver", "physdrape.model.stretching_solver", "StretchingSolver", "forward", 0),
    ("body requeries", "physdrape.model.relaxation", "Relaxation", "requery", 1),
    ("coarse factorisations", "physdrape.physics.coarse_space", "CoarseSpace", "factor", 1),
    ("forces, stiffness blocks and inverses", "physdrape.model.relaxation", "Relaxation", "step_terms", 1),
    ("coarse solves", "physdrape.physics.coarse_space", "CoarseSpace", "solve", 1),
    ("stiffness products (inner iterations)", "physdrape.physics.coarse_space", "CoarseSpace", "stiffness_product", 1),
    ("line-search potentials", "physdrape.model.relaxation", "Relaxation", "potential", 1),
    ("collision handler", "physdrape.model.collision_handler", "CollisionHandler", "forward", 0),
]
#: The Warp kernels of the body BVH searches (`geometry.body_bvh`), by their function names.
BVH_KERNELS = ("closest_kernel", "closest_winding_kernel", "ray_kernel")


class Timers:
    """Accumulated seconds and calls per label while `active`."""

    def __init__(self) -> None:
        self.seconds: dict[str, float] = collections.defaultdict(float)
        self.calls: dict[str, int] = collections.defaultdict(int)
        self.active = False
        self.sync = lambda: None  # waits for the device's queued work (the GPU's), before and after a timed call

    def wrap(self, owner, attribute: str, label: str) -> None:
        original = getattr(owner, attribute)
        depth = [0]  # a method that calls itself (the network, piece by piece) is timed at the outer call

        def timed(*args, **kwargs):
            if not self.active or depth[0]:
                return original(*args, **kwargs)
            self.sync()
            start = time.perf_counter()
            depth[0] += 1
            try:
                return original(*args, **kwargs)
            finally:
                depth[0] -= 1
                self.sync()
                self.seconds[label] += time.perf_counter() - start
                self.calls[label] += 1

        setattr(owner, attribute, timed)

    def wrap_warp(self) -> None:
        """Time every Warp CPU kernel invocation (`warp._src.context.invoke`, where a kernel's
        compiled code runs), the BVH searches apart."""
        from warp._src import context

        original = context.invoke

        def timed(kernel, hooks, params, adjoint):
            if not self.active:
                return original(kernel, hooks, params, adjoint)
            start = time.perf_counter()
            try:
                return original(kernel, hooks, params, adjoint)
            finally:
                spent = time.perf_counter() - start
                self.seconds["warp kernels"] += spent
                self.calls["warp kernels"] += 1
                if kernel.func.__name__ in BVH_KERNELS:
                    self.seconds["BVH searches"] += spent
                    self.calls["BVH searches"] += 1

        context.invoke = timed

    def take(self) -> tuple[dict[str, float], dict[str, int]]:
        out = dict(self.seconds), dict(self.calls)
        self.seconds.clear()
        self.calls.clear()
        return out


def measure(repeats: int, device: str = "cpu") -> dict[str, list[dict]]:
    import importlib

    import torch

    torch.set_num_threads(1)
    timers = Timers()
    if device != "cpu":
        timers.sync = torch.cuda.synchronize
    for label, module, owner, attribute, _ in PHASES:
        place = importlib.import_module(module)
        timers.wrap(place if owner is None else getattr(place, owner), attribute, label)
    timers.wrap_warp()
    from physdrape.api import Draper

    draper = Draper(device=device)
    draper.drape("default")  # fits the skinning transfer, poses the default body
    poses = [draper.poses(f"random:{1000 + k}")[0].pose[0] for k in range(repeats + 1)]
    eight = [draper.poses(f"random:{k}")[0].pose[0] for k in range(8)]  # bench_drape.py's batch
    draper.drape("default", pose=poses[0])  # a first new pose outside the timing
    draper.drape("default", pose=eight, batch_size=8)  # the batch's bodies posed outside the timing
    out: dict[str, list[dict]] = {"same_pose": [], "new_pose": [], "batch8": []}
    for k in range(repeats):
        for row, rows in out.items():
            timers.active = True
            start = time.perf_counter()
            if row == "same_pose":
                results = draper.drape("default")
            elif row == "new_pose":
                results = draper.drape("default", pose=poses[k + 1])
            else:
                results = draper.drape("default", pose=eight, batch_size=8)
            wall = time.perf_counter() - start
            timers.active = False
            seconds, calls = timers.take()
            timings = results[0].timings  # a batch's phases, the same in each of its results
            seconds.update({"init phase": timings["init_s"], "metrics": timings["metrics_s"], "drape": wall})
            n = len(results)  # per garment
            rows.append({"seconds": {key: value / n for key, value in seconds.items()},
                         "calls": {key: value / n for key, value in calls.items()}})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=9, help="timed drapes per column (the columns alternate)")
    parser.add_argument("--device", default="cpu", choices=["cpu", "cuda"])
    parser.add_argument("--out", default="results/drape_breakdown")
    args = parser.parse_args()
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    from report import source_lines, write_report

    from physdrape.provenance import provenance

    samples = measure(args.repeats, args.device)
    load = os.getloadavg()
    labels = [("drape (end to end)", "drape", 0)]
    labels += [(label, label, indent) for label, *_, indent in PHASES[:2]]
    labels += [("init phase (the pipeline's build)", "init phase", 0)]
    labels += [(label, label, indent) for label, *_, indent in PHASES[2:]]
    labels += [("metrics", "metrics", 0), ("in Warp kernels (all phases)", "warp kernels", 0),
               ("BVH searches", "BVH searches", 1)]

    def median_ms(row: str, key: str) -> float:
        return 1e3 * statistics.median(s["seconds"].get(key, 0.0) for s in samples[row])

    def calls(row: str, key: str) -> str:
        if key in ("drape", "init phase", "metrics"):  # one phase of each drape
            return "1" if row != "batch8" else "1/8"
        if key == "solver, the rest":
            return "–"
        median = statistics.median(s['calls'].get(key, 0) for s in samples[row])
        return f"{median:.0f}" if float(median).is_integer() else f"{median:.2f}"

    medians = {row: {key: median_ms(row, key) for _, key, _ in labels} for row in samples}
    solver = [label for label, *_ in PHASES].index("stretching solver")
    for row in samples:  # what the solver's timed parts leave: conjugation, clips, updates
        parts = [label for label, *_, indent in PHASES[solver + 1:] if indent == 1]
        medians[row]["solver, the rest"] = 1e3 * statistics.median(
            s["seconds"].get("stretching solver", 0.0) - sum(s["seconds"].get(p, 0.0) for p in parts)
            for s in samples[row])
    solver_end = labels.index(("line-search potentials", "line-search potentials", 1))
    labels.insert(solver_end + 1, ("the rest (conjugation, clips, updates)", "solver, the rest", 1))
    command = shlex.join(["python", *sys.argv])
    info = provenance()
    where = "one thread" if args.device == "cpu" else f"one thread, the drape on {args.device}"
    lines = [f"# Where a warm drape's time goes (bundled model, T = 15, {where})", "", *source_lines(command, info),
             (f"Default T-shirt; medians over {args.repeats} drapes per column, the columns alternating; load average "
              f"at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}. Indented rows are part of the unindented row above "
              "them; calls: per drape. The batch of 8 poses (one `drape` call, the bodies posed before): its time and "
              "calls per garment (the init phase and the metrics are one each per batch)."), "",
             "| phase | same pose [ms] | calls | new pose [ms] | calls | batch of 8, per garment [ms] | calls |",
             "|---|---:|---:|---:|---:|---:|---:|"]
    for label, key, indent in labels:
        name = ("&nbsp;&nbsp;&nbsp;&nbsp;" * indent) + label
        lines.append(f"| {name} | " + " | ".join(f"{medians[row][key]:.1f} | {calls(row, key)}"
                                                 for row in ("same_pose", "new_pose", "batch8")) + " |")
    write_report(args.out, lines, {"command": command, "provenance": info, "device": args.device, "load_average_end": load,
                                   "repeats": args.repeats, "medians_ms": medians, "samples": samples})


if __name__ == "__main__":
    main()

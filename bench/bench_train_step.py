"""A training step of the shipped recipe's stage on the cached instances, beside an earlier commit.

    .venv/bin/python bench/bench_train_step.py [--config configs/global/gnn_step_inputs.yaml]
        [--base COMMIT] [--steps 30] [--compile] [--out results/bench_train_step]

One process builds a `Trainer` of `--config` (its instance cache, `data.instances`, built before
if missing) for this commit's package and, with `--base`, for that commit's (exported beside it,
as `bench/bench_drape.py` does), one torch thread, the network eager (`--compile`: compiled by
`torch.compile` for both, as `physdrape train --compile` runs it); each warms up its input
normalisers, then the two take turns step by step (the same seeds, so both draw the same instances
at each step) for `--steps` steps each. This commit's trainer first meets every training instance
once (`Trainer.node_inputs` then holds the network's inputs at each instance's X_init, as a run
does after its first few hundred steps), and each package builds every instance's coarse space once (kept
as far as the package keeps them): the rows are the steady state of a long run. Each step is made as
the package's own `Trainer.run` makes it (where `train_step` takes `measure`, the batch's B2G is
measured at the steps the run logs, every `optim.log_every`, only). Prints and writes
<out>.md and <out>.json: the median step per package, the median of the paired ratios, the load
average.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from bench_drape import export_base
from report import page_head, write_report

ROOT = Path(__file__).resolve().parent.parent


def _trainer(package: str, config_path: str, run_dir: str, compile_network: bool):
    config_io = importlib.import_module(f"{package}.config_io")
    data = importlib.import_module(f"{package}.train.data")
    trainer_module = importlib.import_module(f"{package}.train.trainer")
    config = config_io.load_config(trainer_module.TrainConfig, config_path)
    source = data.DrapeSource(config.data, model=config.model)
    trainer = trainer_module.Trainer(config, source, run_dir, progress=False, tensorboard=False,
                                     compile_network=compile_network)
    trainer.warm_up_normalizers()
    return trainer, source


def _meet_every_instance(package: str, trainer, source) -> None:
    """Meet each training instance once (4 per batch), as a long run has: its garment's coarse
    space built (kept as far as the package keeps them) and, where the trainer holds the network's
    inputs, those handed to it."""
    pipeline = importlib.import_module(f"{package}.pipeline")
    physics = importlib.import_module(f"{package}.physics")
    data = importlib.import_module(f"{package}.train.data")
    coarse_space = importlib.import_module(f"{package}.physics.coarse_space")
    model = trainer.config.model
    count = len(source._train)
    for start in range(0, count, 4):
        picks = list(range(start, min(count, start + 4)))
        jobs = [pipeline.Job(source.templates[source._train[i].garment], source._train[i].body,
                             physics.Material(**source._train[i].material), source._tensors[i][0]) for i in picks]
        batch = source.pipeline.build(jobs, source.posed_pool())
        coarse_space.CoarseSpace(batch.cloth, levels=model.coarse_levels, smoothing=model.coarse_smoothing)
        if hasattr(trainer, "node_inputs"):
            trainer.node_inputs.attach(data.TrainingBatch(batch, None, tuple(picks)))


def worker(packages: list[str], config_path: str, steps: int, compile_network: bool) -> dict[str, list[float]]:
    import torch

    torch.set_num_threads(1)
    trainers = {}
    with tempfile.TemporaryDirectory() as tmp:
        for package in packages:
            trainer, source = _trainer(package, config_path, f"{tmp}/{package}", compile_network)
            if compile_network:
                trainer.train_step()  # compiles the network's forward and backward, outside the timing
            _meet_every_instance(package, trainer, source)
            trainers[package] = trainer
        times = {package: [] for package in packages}
        for k in range(steps):
            for package in packages if k % 2 == 0 else packages[::-1]:
                trainer = trainers[package]
                options = {}
                if "measure" in inspect.signature(trainer.train_step).parameters:  # as its `run` asks
                    options["measure"] = (trainer.step + 1) % trainer.config.optim.log_every == 0
                start = time.perf_counter()
                trainer.train_step(**options)
                times[package].append(1e3 * (time.perf_counter() - start))
    return times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", default="configs/global/gnn_step_inputs.yaml")
    parser.add_argument("--base", default=None)
    parser.add_argument("--steps", type=int, default=30)
    parser.add_argument("--compile", action="store_true", help="both packages' networks compiled by torch.compile")
    parser.add_argument("--out", default="results/bench_train_step")
    parser.add_argument("--worker", nargs="+", default=None, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        print(json.dumps(worker(args.worker, args.config, args.steps, args.compile)))
        return
    command, prov, head = page_head("A training step on the cached instances")
    with tempfile.TemporaryDirectory() as tmp:
        paths, packages = [ROOT / "src"], ["physdrape"]
        if args.base:
            paths.append(export_base(args.base, Path(tmp)))
            packages.append("physdrape_base")
        env = dict(os.environ, OMP_NUM_THREADS="1", PYTHONPATH=os.pathsep.join(
            [*(str(p) for p in paths), *filter(None, [os.environ.get("PYTHONPATH")])]))
        proc = subprocess.run([sys.executable, __file__, "--config", args.config, "--steps", str(args.steps),
                               *(["--compile"] if args.compile else []), "--worker", *packages], env=env, cwd=ROOT,
                              capture_output=True, text=True)
        if proc.returncode != 0:
            raise SystemExit(f"the timing process failed:\n{proc.stderr[-3000:]}")
        times = json.loads(proc.stdout.strip().splitlines()[-1])
    load = os.getloadavg()
    base = None
    if args.base:
        base = subprocess.run(["git", "rev-parse", "--short=10", args.base], cwd=ROOT, check=True,
                              capture_output=True, text=True).stdout.strip()
    labels = {"physdrape": "this commit", "physdrape_base": f"base {base}"}
    lines = [*head,
             f"Config `{args.config}` on its instance cache; one torch thread, "
             f"{'the network compiled (torch.compile)' if args.compile else 'eager network'}; {args.steps} steps per "
             "package after the normalisers' warm-up, the packages taking turns step by step on the same seeds; "
             f"load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}.", "",
             "| package | median step [ms] | min–max [ms] |", "|---|---:|---:|"]
    for package, samples in times.items():
        median, low, high = statistics.median(samples), min(samples), max(samples)
        lines.append(f"| {labels[package]} | {median:.0f} | {low:.0f}–{high:.0f} |")
    if args.base:
        ratios = [b / t for t, b in zip(times["physdrape"], times["physdrape_base"])]
        lines += ["", f"Base / this commit, median of the paired steps: {statistics.median(ratios):.2f}."]
    write_report(args.out, lines, {"command": command, "provenance": prov, "config": args.config, "base": base,
                                   "steps": args.steps, "compile": args.compile, "load_average": list(load),
                                   "times_ms": times})


if __name__ == "__main__":
    main()

"""`physdrape drape --manifest jobs.jsonl --out DIR`: drape a manifest of jobs with the API
(`physdrape.api.manifest_run.run_manifest`), this process's share when torchrun starts several
(RANK / WORLD_SIZE), and say what was done, skipped and failed. docs/manifest.md is the user's guide."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

from physdrape.api import Draper, ManifestError, ranks_from_env, read_manifest, run_manifest
from physdrape.api.manifest_run import Outputs, summary_path
from physdrape.cli.common import CLIError, process_device

#: Flags of a single drape that a manifest's lines give per job instead (flag → the job key to use).
PER_JOB_FLAGS = {"garment": "garment", "category": "garment", "seed": "garment", "shape": "shape", "pose": "pose",
                 "bvh": "pose", "frame": "pose", "frames": "pose", "warm_start": "pose", "no_warm_start": "pose",
                 "betas": "shape", "theta": "pose", "amass": "pose", "material": "material", "mu": "material",
                 "lam": "material", "k_bend": "material", "density": "material", "figures": None}


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The flags of `physdrape drape --manifest`."""
    d = parser.add_argument_group("datasets (--manifest; see docs/manifest.md)")
    d.add_argument("--manifest", metavar="JOBS.jsonl", help="drape every job of a JSON-lines file (one JSON object "
                   "per line: id, garment, shape, pose, material, units) into --out/<id>/; finished jobs are "
                   "skipped, so rerunning resumes; under torchrun each rank drapes jobs j with j mod WORLD_SIZE = RANK")
    d.add_argument("--outputs", choices=[o.value for o in Outputs], default=Outputs.LEAN.value,
                   help="files per job: lean (default: garment.ply + report.json), meshes (+ garment.obj, "
                   "body.obj/.ply, drape.glb), full (+ render.png: what a single drape writes)")
    d.add_argument("--skip-bad-lines", action="store_true", help="drape the valid jobs and list the bad lines at the "
                   "end (default: a bad line stops the command before anything is draped)")
    d.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")


def _check_flags(args: argparse.Namespace) -> None:
    given = [flag for flag in PER_JOB_FLAGS if getattr(args, flag, None) is not None and getattr(args, flag) is not False]
    if given:
        flag = given[0]
        key = PER_JOB_FLAGS[flag]
        fix = f"give \"{key}\" in each line of the manifest instead" if key else "it is not available with --manifest"
        raise CLIError(f"--{flag.replace('_', '-')} sets one drape; with --manifest {fix} (docs/manifest.md)")
    if args.batch_size < 1:
        raise CLIError(f"--batch-size must be >= 1, got {args.batch_size}")
    if not 32 <= args.render_size <= 4096:
        raise CLIError(f"--render-size must be in [32, 4096] pixels, got {args.render_size}")
    out = Path(args.out).expanduser()
    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out} exists and is not a directory; choose another path")


def cmd_manifest(args: argparse.Namespace) -> int:
    """Drape this rank's share of --manifest into --out and report what happened."""
    _check_flags(args)
    rank, world_size = ranks_from_env()
    if args.threads:
        torch.set_num_threads(args.threads)
    manifest = read_manifest(args.manifest, smpl=args.smpl_model is not None, units=args.units)
    if manifest.bad and not args.skip_bad_lines:  # before the model is loaded
        raise ManifestError(manifest.path, manifest.bad)
    draper = Draper(args.checkpoint, steps=15 if args.steps is None else args.steps, smpl_model=args.smpl_model,
                    smpl_gender=args.smpl_gender, device=process_device(args.device),
                    follow_planes=args.follow_planes, passes=args.passes, compile_network=args.compile)
    out = Path(args.out).expanduser()
    try:
        summary = run_manifest(draper, manifest, out, rank=rank, world_size=world_size, outputs=args.outputs,
                               batch_size=args.batch_size, refine=args.refine, allow_detached=args.allow_detached,
                               skip_bad_lines=args.skip_bad_lines, force=args.force, progress=not args.no_progress,
                               render_size=args.render_size)
    except KeyboardInterrupt:
        raise KeyboardInterrupt(f"the finished jobs are in {out}; run the same command again to drape the "
                                "rest") from None
    who = "" if world_size == 1 else f"rank {rank}/{world_size}: "
    for bad in summary.bad_lines:
        print(f"physdrape: {who}skipped bad line {bad['line']} of {manifest.path}: {bad['error']}", file=sys.stderr)
    for failed in summary.failed:
        print(f"physdrape: {who}job {failed['id']} (line {failed['line']}) failed: {failed['error']}", file=sys.stderr)
    print(f"{who}{len(summary.done)} job(s) draped, {len(summary.skipped)} already done, {len(summary.failed)} "
          f"failed, {len(summary.bad_lines)} bad line(s) skipped, of {summary.jobs + len(summary.bad_lines)} in this "
          f"share; in {out} (summary: {summary_path(out, rank, world_size).name})")
    return 0

"""`physdrape fit`: place a garment authored for another body onto the canonical body."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from physdrape.api.placement import UNITS
from physdrape.cli.common import CLIError, check_out_dir, deferred_interrupt
from physdrape.progress import slow_phase


def cmd_fit(args: argparse.Namespace) -> int:
    """Place a garment authored for another body onto the canonical body, relax it, validate, write."""
    from physdrape.api import fit_garment
    from physdrape.geometry.mesh import write_mesh

    out = Path(args.out).expanduser()
    if out.suffix.lower() not in (".obj", ".ply"):
        raise CLIError(f"--out {args.out}: the fitted garment is written as .obj or .ply; give such a file name")
    if out.exists() and out.is_dir():
        raise CLIError(f"--out {out} is a directory; give a file name ending in .obj or .ply")
    if out.exists() and not args.force:
        raise CLIError(f"--out {out} exists; pass --force to overwrite it")
    check_out_dir(out.parent, True)
    if args.iters < 0:
        raise CLIError(f"--iters must be >= 0, got {args.iters}")
    t0 = time.perf_counter()
    with slow_phase(f"fitting {Path(args.garment).name}: placing it on the canonical body, untangling its layers"
                    + (f", relaxing it with the physics oracle (at most {args.iters} iterations, "
                       f"{args.time_budget:g} s)" if args.iters else "")):
        result = fit_garment(args.garment, align=not args.no_align, scale=args.scale, iters=args.iters,
                             time_budget_s=args.time_budget, units=args.units)
    report = result.report()
    report["wall_time_s"] = time.perf_counter() - t0
    print(json.dumps(report, indent=2))
    if not result.ok:
        if not args.keep_invalid:
            raise CLIError(f"the fitted garment failed validation (nothing written; --keep-invalid writes it "
                           f"anyway):\n{result.validation}")
        print("physdrape: warning: writing a garment that failed validation (--keep-invalid)", file=sys.stderr)
    with deferred_interrupt(f"{out} was written in full before stopping"):
        write_mesh(out, result.verts, result.faces)  # atomic
    print(f"wrote {out}")
    return 0


def _interrupted(args, argv) -> str:
    out = Path(args.out).expanduser()
    return f"nothing was written to {out}" + ("; the earlier file is unchanged" if out.exists() else "")


def add_parser(sub) -> None:
    """The `fit` subcommand."""
    fit = sub.add_parser("fit", help="place a garment authored for another body onto the canonical body")
    fit.add_argument("garment", help="an .obj/.ply (y-up, in --units) or a MakeHuman .mhclo")
    fit.add_argument("--out", required=True, help="the fitted template (.obj or .ply, in metres)")
    fit.add_argument("--units", choices=tuple(UNITS), default="m", help="unit of an .obj/.ply garment (default m); "
                     "it is converted to metres")
    fit.add_argument("--force", action="store_true", help="overwrite --out")
    fit.add_argument("--iters", type=int, default=20, help="physics relaxation iterations (0: align only)")
    fit.add_argument("--time-budget", type=float, default=120.0, help="relaxation wall-time budget [s]")
    fit.add_argument("--scale", type=float, default=1.0, help="uniform scale applied after --units, in [0.2, 5] (e.g. "
                     "0.95 for a garment made for a taller body; default 1)")
    fit.add_argument("--no-align", action="store_true", help="skip the translation search")
    fit.add_argument("--keep-invalid", action="store_true", help="write the result even if validation fails")
    fit.set_defaults(func=cmd_fit, interrupted=_interrupted)

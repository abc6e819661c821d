"""`physdrape eval`: the evaluation protocol of `physdrape.eval.evaluate` from the command line."""

from __future__ import annotations

import argparse
import shlex
import sys

from physdrape.cli.common import CLIError, deferred_interrupt


def _ablation_pair(text: str) -> tuple[str, str]:
    from physdrape.eval.evaluate import ABLATION_NAMES

    name, sep, path = text.partition("=")
    if not sep or not path or name not in ABLATION_NAMES:
        raise argparse.ArgumentTypeError(f"expected NAME=DIR with NAME one of {list(ABLATION_NAMES)}, got {text!r}")
    return name, path


def cmd_eval(args: argparse.Namespace) -> int:
    """Run the protocol and write <out>/eval.json and <out>/eval.md."""
    from physdrape.eval.evaluate import EvalConfig, evaluate
    from physdrape.eval.report import render_markdown, write_results

    ablation = dict(args.ablation or [])
    try:
        config = EvalConfig(
            instances=args.instances, poses_per_garment=args.poses_per_garment, seed=args.seed,
            oracle=not args.no_oracle, oracle_budget_s=args.oracle_budget, oracle_tol=args.oracle_tol,
            oracle_max_iters=args.oracle_max_iters, oracle_refine=not args.no_oracle_refine,
            oracle_settle_steps=args.oracle_settle_steps,
            reference_cache=None if args.no_reference_cache else (args.reference_cache or ""),
            split_dir=args.split_dir or "", max_garments=args.max_garments, makehuman_dir=args.makehuman or "",
            makehuman_max_verts=args.makehuman_max_verts, threads=args.threads,
            **({"dtype": args.dtype} if args.dtype else {}),
        )
    except ValueError as exc:  # a bad flag value: exit 2 with the message, no traceback
        raise CLIError(f"{exc} (see physdrape eval --help)") from None
    command = shlex.join(["physdrape", *sys.argv[1:]])
    results = evaluate(args.checkpoint, config, ablation=ablation, command=command,
                       log=lambda msg: print(msg, file=sys.stderr))
    with deferred_interrupt(f"{args.out} was written in full before stopping"):  # eval.json with eval.md
        json_path, md_path = write_results(results, args.out)
    print(render_markdown(results))
    print(f"wrote {json_path} and {md_path}", file=sys.stderr)
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    """Add the `eval` subcommand to the `physdrape` parser's subparsers."""
    p = subparsers.add_parser("eval", help="evaluate a checkpoint: Tables 1–2 vs. the physics oracle")
    p.add_argument("--checkpoint", required=True, help="checkpoint directory (or a run directory: its latest)")
    p.add_argument("--out", required=True, help="output directory for eval.json and eval.md")
    p.add_argument("--instances", type=int, default=None,
                   help="test instances: the first N of the layout (instance i: test garment i mod G in pose i div G, "
                        "each on a body of its own seed); default: every test garment, --poses-per-garment times")
    p.add_argument("--poses-per-garment", type=int, default=1,
                   help="bodies (shape and pose) per test garment when --instances is not given")
    p.add_argument("--seed", type=int, default=0, help="seed of the body shapes and poses")
    p.add_argument("--oracle-budget", type=float, default=60.0, help="oracle wall-time budget per instance [s]")
    p.add_argument("--oracle-tol", type=float, default=1e-2, help="oracle residual tolerance (|F|/(m g))")
    p.add_argument("--oracle-max-iters", type=int, default=200, help="oracle Newton iteration cap per instance")
    p.add_argument("--no-oracle", action="store_true", help="skip the oracle (no ratio columns)")
    p.add_argument("--no-oracle-refine", action="store_true",
                   help="do not also run the oracle from the PhysDrape (T=15) drape (ratios then use the oracle alone)")
    p.add_argument("--oracle-settle-steps", type=int, default=60,
                   help="also run the oracle from the model's drape at this T, which can end in a lower equilibrium "
                        "(the reference is the lowest oracle result; 0: not)")
    cache = p.add_mutually_exclusive_group()
    cache.add_argument("--reference-cache", metavar="DIR",
                       help="folder of the oracle results from the skinned start, reused by later evaluations of the "
                            "same instances and settings (default: ~/.cache/physdrape/eval_reference)")
    cache.add_argument("--no-reference-cache", action="store_true",
                       help="run the oracle from the skinned start on every instance, reading and writing no cache")
    p.add_argument("--makehuman", metavar="DIR", help="also evaluate the CC0 MakeHuman garments (.mhclo) in DIR")
    p.add_argument("--makehuman-max-verts", type=int, default=0,
                   help="skip MakeHuman garments with more vertices (0: no cap)")
    p.add_argument("--ablation", action="append", type=_ablation_pair, metavar="NAME=DIR",
                   help="a separately trained checkpoint for Table 2 (NAME: gnn, gnn+solver, gnn+collision, full)")
    p.add_argument("--split-dir", help="garment split directory (default: the cached seed-0 split)")
    p.add_argument("--max-garments", type=int, default=0, help="use the first N test garments (0: all)")
    p.add_argument("--dtype", choices=("float32", "float64"), default=None,
                   help="dtype of the garments, bodies and physics (default: the API's, float32)")
    p.add_argument("--threads", type=int, default=1, help="torch threads (0: torch's default)")
    p.set_defaults(func=cmd_eval, interrupted=lambda args, argv: f"nothing was written to {args.out}")
    return p

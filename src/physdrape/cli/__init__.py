"""The `physdrape` command line: one module per subcommand (`drape`, `fit`, `train`, `eval`).

The subcommands parse flags into the public API's arguments and call the API (`physdrape.api`),
the trainer or the evaluation; they rely on those to validate what they are given. Bad input
exits with code 2 and a one-line message on stderr; no traceback. Ctrl-C exits with code 130 and
one line saying what was kept (a subcommand's ``interrupted(args, argv)`` tells it); outputs are
written beside their place and moved in whole, so an interrupted command leaves none half-written.
"""

from __future__ import annotations

import argparse
import sys

from physdrape.api.types import DrapeError
from physdrape.checkpoint import CheckpointError
from physdrape.cli import drape, eval, fit, train
from physdrape.cli.common import CLIError
from physdrape.config_io import ConfigError
from physdrape.geometry.mesh import MeshError

#: Errors that are the user's input, not a bug: reported in one line with exit code 2.
USER_ERRORS = (CLIError, MeshError, ConfigError, CheckpointError, DrapeError)
#: The exit status of a command stopped by Ctrl-C (128 + SIGINT, as shells report it).
INTERRUPTED = 130


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="physdrape", description="Drape garments onto bodies with PhysDrape.")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in (drape, fit, train, eval):
        command.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else list(argv)
    args = None
    try:
        args = build_parser().parse_args(argv)
        return args.func(args)
    except USER_ERRORS as exc:
        print(f"physdrape: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        note = exc.args[0] if exc.args else None
        if note is None and args is not None and hasattr(args, "interrupted"):
            note = args.interrupted(args, argv)
        print("physdrape: interrupted" + (f"; {note}" if note else ""), file=sys.stderr)
        return INTERRUPTED

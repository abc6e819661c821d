"""The `physdrape` command line: one module per subcommand (`drape`, `fit`, `train`, `eval`).

The subcommands parse flags into the public API's arguments and call the API (`physdrape.api`),
the trainer or the evaluation; they rely on those to validate what they are given. Bad input
exits with code 2 and a one-line message on stderr; no traceback.
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="physdrape", description="Drape garments onto bodies with PhysDrape.")
    sub = parser.add_subparsers(dest="command", required=True)
    for command in (drape, fit, train, eval):
        command.add_parser(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except USER_ERRORS as exc:
        print(f"physdrape: error: {exc}", file=sys.stderr)
        return 2


"""How a benchmark records its result: a Markdown page headed by the command and the commit that
wrote it, printed and written beside its JSON record, each file atomically."""

from __future__ import annotations

import json
import shlex
import sys

from physdrape.atomic import write_text
from physdrape.provenance import provenance


def source_lines(command: str, provenance: dict) -> list[str]:
    """The Markdown lines naming the command and the git commit (and whether the tree differed)."""
    dirty = " (with uncommitted changes)" if provenance["git_dirty"] else ""
    return [f"Command: `{command}`  ", f"Git commit: `{provenance['git_commit']}`{dirty}  "]


def page_head(title: str) -> tuple[str, dict, list[str]]:
    """This run's command line, its provenance and the page's first lines: the title, the command
    and the commit."""
    prov = provenance()
    command = " ".join(["python", *map(shlex.quote, sys.argv)])
    return command, prov, [f"# {title}", "", *source_lines(command, prov)]


def write_report(out: str, lines: list[str], record: dict) -> None:
    """Print the page `lines` and write it to <out>.md, and `record` to <out>.json."""
    text = "\n".join(lines) + "\n"
    print(text)
    write_text(f"{out}.md", text)
    write_text(f"{out}.json", json.dumps(record, indent=1) + "\n")

"""Training runs side by side on their held-out curves (`physdrape.train.validation`).

    python -m physdrape.train.compare NAME=RUN_DIR [NAME=RUN_DIR ...] --out results/training_signal \
        [--checkpoint NAME=DIR --config CONFIG.yaml [--passes 1 2 ...]]

For every run, the rows of its validation.jsonl (or of a shipped record's) at each validated
step, and for every --checkpoint (a model trained elsewhere, e.g. an earlier bundled model) the
same rows measured now on the validation set of CONFIG's data section (with --passes, once per
number of network passes, `ModelConfig.passes`): E_total / teacher and the energy gap left for
GNN only, T = 3 and T = 15, E_strain / teacher at T = 15, B2G at T = 15, and the network-free
solver's rows once. Writes OUT.md and OUT.json atomically, naming the command and the commit.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
from pathlib import Path

from physdrape.atomic import write_text
from physdrape.provenance import provenance
from physdrape.train.curves import read_metrics

#: (column title, key) of the table, in order.
COLUMNS = (
    ("GNN only E/teacher", "gnn/energy_ratio"), ("GNN only gap", "gnn/energy_gap"),
    ("T=3 E/teacher", "t3/energy_ratio"), ("T=3 gap", "t3/energy_gap"),
    ("T=15 E/teacher", "t15/energy_ratio"), ("T=15 gap", "t15/energy_gap"),
    ("T=15 E_strain/teacher", "t15/strain_ratio"), ("T=15 B2G %", "t15/b2g_percent"),
)


def _validation(run: Path) -> list[dict]:
    path = run / "validation.jsonl"
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: the run logged no held-out curve (optim.validate_every 0, or "
                                "no instance cache)")
    return read_metrics(path)


def compare(runs: dict[str, Path], checkpoints: dict[str, Path] | None = None, config: Path | None = None,
            passes: list[int] | None = None) -> dict:
    """Every run's held-out rows per validated step, every checkpoint's rows on the validation
    set of `config`'s data section (step None; with `passes`, a row per number of network passes,
    named "NAME, k passes"), and the network-free solver's rows."""
    table, solver = {}, {}
    for name, run in runs.items():
        records = _validation(run)
        table[name] = [{"step": r["step"], **{key: r.get(key) for _, key in COLUMNS}} for r in records]
        solver = solver or {k: v for k, v in records[0].items() if k.startswith("solver_")}
    if checkpoints:
        from physdrape.checkpoint import load_model
        from physdrape.config_io import load_config
        from physdrape.train.data import DrapeSource
        from physdrape.train.trainer import TrainConfig
        from physdrape.train.validation import Validator

        if config is None:
            raise ValueError("--checkpoint needs --config: the run config whose data section names the validation set")
        train_config = load_config(TrainConfig, config)
        validator = Validator(DrapeSource(train_config.data, model=train_config.model).validation())
        for name, path in checkpoints.items():
            for k in passes or [None]:
                row = validator(load_model(path, passes=k)[0])
                label = name if k is None else f"{name}, {k} pass{'es' if k > 1 else ''}"
                table[label] = [{"step": None, **{key: row.get(key) for _, key in COLUMNS}}]
    return {"runs": {name: str(path) for name, path in {**runs, **(checkpoints or {})}.items()}, "rows": table,
            "solver_alone": solver, **({"passes": passes} if passes else {})}


def _markdown(result: dict, command: str, commit: str | None) -> str:
    lines = ["# Training runs on the held-out validation set", "", f"Command: `{command}`  ",
             f"Git commit: `{commit}`", "",
             "Rows: the validation instances draped with each run's weights at each validated step. E/teacher: mean "
             "E_total over the set divided by the teacher drapes' (the two-level solver run to near convergence from "
             "the same X_init); gap: the share of X_init's excess energy over the teacher that is left (1 at X_init, "
             "0 at the teacher). Step –: a checkpoint measured on the same set by this command.", "",
             "| run | step | " + " | ".join(title for title, _ in COLUMNS) + " |",
             "|---|---:|" + "---:|" * len(COLUMNS)]
    for name, rows in result["rows"].items():
        for r in rows:
            cells = [f"{r[key]:.3f}" if r[key] is not None else "–" for _, key in COLUMNS]
            step = "–" if r["step"] is None else r["step"]
            lines.append(f"| {name} | {step} | " + " | ".join(cells) + " |")
    s = result["solver_alone"]
    if s:
        lines += ["", "The network-free solver on the same set (Δx = 0, f̂ = 0): "
                  f"T = 3 E/teacher {s['solver_t3/energy_ratio']:.3f} (gap {s['solver_t3/energy_gap']:.3f}), "
                  f"T = 15 E/teacher {s['solver_t15/energy_ratio']:.3f} (gap {s['solver_t15/energy_gap']:.3f})."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Training runs side by side on their held-out curves.")
    parser.add_argument("runs", nargs="*", metavar="NAME=RUN_DIR")
    parser.add_argument("--out", required=True, help="output stem: writes OUT.md and OUT.json")
    parser.add_argument("--checkpoint", action="append", default=[], metavar="NAME=DIR",
                        help="a model to measure on the validation set now (repeatable)")
    parser.add_argument("--config", type=Path, help="run config whose data section names the validation set "
                        "(needed with --checkpoint)")
    parser.add_argument("--passes", type=int, nargs="+", help="measure every --checkpoint with each of these numbers "
                        "of network passes (default: the checkpoint's own)")
    args = parser.parse_args(argv)
    if args.passes and (not args.checkpoint or min(args.passes) < 1):
        parser.error("--passes takes numbers ≥ 1 and applies to --checkpoint models")

    def named(items: list[str]) -> dict[str, Path]:
        out = {}
        for item in items:
            name, sep, path = item.partition("=")
            if not sep or not name:
                parser.error(f"{item!r}: give NAME=PATH")
            out[name] = Path(path)
        return out

    if not args.runs and not args.checkpoint:
        parser.error("give at least one NAME=RUN_DIR or --checkpoint NAME=DIR")
    result = compare(named(args.runs), named(args.checkpoint), args.config, args.passes)
    command = shlex.join(["python", "-m", "physdrape.train.compare", *(sys.argv[1:] if argv is None else argv)])
    info = provenance()
    commit = info["git_commit"] + (" (with uncommitted changes)" if info["git_dirty"] else "")
    text = _markdown(result, command, commit)
    write_text(f"{args.out}.md", text)
    write_text(f"{args.out}.json", json.dumps({"command": command, "provenance": info, **result}, indent=1) + "\n")
    print(text)


if __name__ == "__main__":
    main()

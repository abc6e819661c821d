"""Ship a trained model: its weights and config into the package, its training record into docs.

    python -m physdrape.train.ship RUN_DIR --model-out src/physdrape/assets/models/cpu_default \\
        --record-out docs/training/RUN --command "physdrape train --config ... --run-dir ..."

Writes MODEL_OUT/{model.safetensors, config.json} (no optimiser state) and RECORD_OUT/
{metrics.jsonl, loss_curve.png, record.json} (step, wall time, seed, config, command), with
validation.jsonl and validation_curve.png when the run logged a held-out curve.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from physdrape.atomic import write_text
from physdrape.checkpoint import export_model, latest_checkpoint, read_checkpoint
from physdrape.train.curves import plot_metrics, plot_validation, read_metrics


def ship(run_dir: str | Path, model_out: str | Path, record_out: str | Path, *, command: str) -> dict:
    """Export the run's latest checkpoint and write its training record; returns the record."""
    export_model(_latest(run_dir), model_out)
    return write_record(run_dir, record_out, command=command)


def _latest(run_dir: str | Path) -> Path:
    checkpoint = latest_checkpoint(Path(run_dir))
    if checkpoint is None:
        raise FileNotFoundError(f"{run_dir} has no checkpoint (no `latest` file): train first")
    return checkpoint


def write_record(run_dir: str | Path, record_out: str | Path, *, command: str) -> dict:
    """Write the training record of the run's latest checkpoint into record_out; returns it."""
    run_dir = Path(run_dir)
    checkpoint = _latest(run_dir)
    _, config = read_checkpoint(checkpoint)
    step = int(checkpoint.name.split("-")[1])
    records = [r for r in read_metrics(run_dir / "metrics.jsonl") if r["step"] <= step]
    record_out = Path(record_out)
    record_out.mkdir(parents=True, exist_ok=True)
    write_text(record_out / "metrics.jsonl", "".join(json.dumps(r) + "\n" for r in records))
    plot_metrics(records, record_out / "loss_curve.png", window=50)
    validation = run_dir / "validation.jsonl"
    if validation.is_file():
        held_out = [r for r in read_metrics(validation) if r["step"] <= step]
        write_text(record_out / "validation.jsonl", "".join(json.dumps(r) + "\n" for r in held_out))
        plot_validation(held_out, record_out / "validation_curve.png")
    tail = records[-50:]
    record = {
        "command": command,
        "checkpoint": checkpoint.name,
        "step": step,
        "seed": config["train"]["optim"]["seed"],
        "wall_time_s_last_segment": records[-1]["wall_s"] if records else None,
        "median_loss_last_50_logs": sorted(r["loss"] for r in tail)[len(tail) // 2] if tail else None,
        "median_loss_first_50_logs": sorted(r["loss"] for r in records[:50])[len(records[:50]) // 2] if records else None,
        "config": config,
    }
    write_text(record_out / "record.json", json.dumps(record, indent=2, sort_keys=True) + "\n")
    return record


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Ship a trained model and its training record.")
    parser.add_argument("run_dir")
    parser.add_argument("--model-out", required=True)
    parser.add_argument("--record-out", required=True)
    parser.add_argument("--command", required=True, help="the training command that produced the run")
    args = parser.parse_args(argv)
    record = ship(args.run_dir, args.model_out, args.record_out, command=args.command)
    print(json.dumps({k: v for k, v in record.items() if k != "config"}, indent=2))


if __name__ == "__main__":
    main()

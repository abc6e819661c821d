"""Training curves from a run's metrics.jsonl, and the held-out curve from its validation.jsonl,
as PNGs (headless matplotlib).

    python -m physdrape.train.curves RUN_DIR/metrics.jsonl OUT.png
    python -m physdrape.train.curves RUN_DIR/validation.jsonl OUT.png --validation
"""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

import numpy as np

from physdrape.atomic import atomic_path


def read_metrics(path: str | os.PathLike) -> list[dict]:
    """The records of a metrics.jsonl file, in order."""
    return [json.loads(line) for line in Path(path).read_text().splitlines() if line.strip()]


def running_median(values: np.ndarray, window: int) -> np.ndarray:
    """Median over the last `window` values at each point (robust to the loss's heavy tail)."""
    return np.array([np.median(values[max(0, i - window + 1):i + 1]) for i in range(len(values))])


def plot_metrics(records: list[dict], out: str | os.PathLike, *, window: int = 25) -> None:
    """Loss and each energy term (log scale, raw and running median), B2G and η, γ, δ over steps."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.array([r["step"] for r in records])
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.2))
    ax = axes[0]
    for key, colour in (("loss", "k"), ("strain", "tab:blue"), ("bend", "tab:orange"), ("collision", "tab:red")):
        values = np.array([max(r[key], 1e-12) for r in records])
        ax.plot(steps, values, color=colour, alpha=0.2, lw=0.8)
        ax.plot(steps, running_median(values, window), color=colour, lw=1.8, label=f"{key} (running median)")
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("energy per garment [J]")
    ax.set_title("training loss terms (E_grav not shown: offset)")
    ax.legend(fontsize=8)
    ax = axes[1]
    b2g = np.array([r["b2g_percent"] for r in records])
    ax.plot(steps, b2g, color="tab:red", alpha=0.3, lw=0.8)
    ax.plot(steps, running_median(b2g, window), color="tab:red", lw=1.8)
    ax.set_xlabel("step")
    ax.set_ylabel("B2G [%]")
    ax.set_title("interpenetration of the training batch")
    ax = axes[2]
    for key in ("eta", "gamma", "delta"):
        ax.plot(steps, [r[key] for r in records], label=key)
    ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_title("learned η (explicit solver: m/N; two-level: a step fraction), γ, δ")
    ax.legend(fontsize=8)
    _save(fig, out)


def _save(fig, out: str | os.PathLike) -> None:
    """Write the figure as a PNG atomically and close it."""
    import matplotlib.pyplot as plt

    fig.tight_layout()
    try:
        with atomic_path(out) as tmp:
            fig.savefig(tmp, dpi=110, format="png")
    finally:
        plt.close(fig)


#: Held-out rows drawn (`physdrape.train.validation.ROWS`) and their colours.
VALIDATION_ROWS = {"gnn": "tab:purple", "t3": "tab:blue", "t15": "tab:green", "solver_t3": "tab:blue",
                   "solver_t15": "tab:green"}


def plot_validation(records: list[dict], out: str | os.PathLike) -> None:
    """The held-out rows over training steps: the fraction of X_init's excess energy over the
    teacher left (energy_gap; the network-free solver rows dashed) and E_total / teacher."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    steps = np.array([r["step"] for r in records])
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for ax, metric, label in ((axes[0], "energy_gap", "energy gap left: (E − E_teacher) / (E_init − E_teacher)"),
                              (axes[1], "energy_ratio", "E_total / E_total of the teacher")):
        for row, colour in VALIDATION_ROWS.items():
            key = f"{row}/{metric}"
            if not all(key in r for r in records):
                continue
            dashed = row.startswith("solver_")
            ax.plot(steps, [r[key] for r in records], color=colour, ls="--" if dashed else "-", marker=None if dashed
                    else "o", ms=3, label=row.replace("solver_", "solver alone, ").replace("t3", "T = 3")
                    .replace("t15", "T = 15").replace("gnn", "GNN only"))
        ax.set_xlabel("step")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    axes[0].set_yscale("log")
    fig.suptitle("held-out validation set (garments and bodies never trained on)", fontsize=11)
    _save(fig, out)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description="Plot a training run's metrics.jsonl.")
    parser.add_argument("metrics", help="path of metrics.jsonl")
    parser.add_argument("out", help="PNG to write")
    parser.add_argument("--window", type=int, default=25, help="running-median window [log records]")
    parser.add_argument("--validation", action="store_true", help="the file is a validation.jsonl")
    args = parser.parse_args(argv)
    if args.validation:
        plot_validation(read_metrics(args.metrics), args.out)
    else:
        plot_metrics(read_metrics(args.metrics), args.out, window=args.window)


if __name__ == "__main__":
    main()

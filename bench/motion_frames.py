"""Motion-capture frames draped one by one: how many are refused, torn or left inside the body.

    .venv/bin/python bench/motion_frames.py [--stride 25] [--garment default --garment longsleeve:3]
        [--bvh-dir ../shared/data/cmu_bvh] [--out results/motion_frames]

Every `stride`-th frame of each BVH file, each frame draped on its own (`Motion(path, frames=k,
warm_start=False)`, the bundled model, T = 15, one torch thread) with the frames as recorded
(`clear_arms=False`) and with the arms turned out where they hang against the torso (the default,
`body/arm_clearance.py`; a checkout without that option drapes the frames as recorded only). Per
garment and variant: the frames refused (arms through the torso), the frames draped with part of
the garment inside the body (B2G > 0) and with a torn garment (E_strain above 1 J: a draped
T-shirt holds about 0.01–0.1 J), the median and largest E_strain, the mean and largest B2G, and
how many frames had their arms turned and by how much. Writes <out>.md and <out>.json with the
command and the commit.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import sys
import warnings
from pathlib import Path

import torch
from report import page_head, write_report

#: E_strain [J] above which a drape counts as torn (a draped T-shirt holds about 0.01–0.1 J).
TORN_J = 1.0


def drape_frames(draper, motion_type, path: Path, frames: list[int], garment: str, clear: bool | None) -> list[dict]:
    """Each frame draped on its own: its metrics, or that it was refused."""
    from physdrape.api import DrapeError

    rows = []
    for k in frames:
        options = {} if clear is None else {"clear_arms": clear}
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                [res] = draper.drape(garment, pose=motion_type(path, frames=k, warm_start=False, **options))
        except DrapeError as exc:
            rows.append({"file": path.name, "frame": k, "refused": str(exc).split(":")[0]})
            continue
        turned = getattr(res, "arms_turned_out_deg", None)
        rows.append({"file": path.name, "frame": k, "strain_J": float(res.metrics["strain"]),
                     "b2g_percent": float(res.metrics["b2g_percent"]),
                     "residual_N": float(res.metrics["residual_force"]),
                     "turned_deg": None if turned is None else list(turned)})
    return rows


def summary(rows: list[dict]) -> dict:
    draped = [r for r in rows if "refused" not in r]
    strain = [r["strain_J"] for r in draped]
    b2g = [r["b2g_percent"] for r in draped]
    turns = [max(r["turned_deg"]) for r in draped if r["turned_deg"]]
    return {"frames": len(rows), "refused": len(rows) - len(draped), "draped": len(draped),
            "inside": sum(b > 0 for b in b2g), "torn": sum(s > TORN_J for s in strain),
            "median_strain_J": statistics.median(strain) if strain else None,
            "max_strain_J": max(strain, default=None),
            "mean_b2g_percent": statistics.mean(b2g) if b2g else None, "max_b2g_percent": max(b2g, default=None),
            "turned": len(turns), "median_turn_deg": statistics.median(turns) if turns else None,
            "max_turn_deg": max(turns, default=None)}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stride", type=int, default=25)
    parser.add_argument("--garment", action="append", help="garment spec (repeatable; default: default)")
    parser.add_argument("--bvh-dir", default=str(Path(__file__).resolve().parents[2] / "shared" / "data" / "cmu_bvh"))
    parser.add_argument("--out", default="results/motion_frames")
    args = parser.parse_args(argv)
    torch.set_num_threads(1)
    from physdrape.api import Draper, Motion
    from physdrape.body.bvh import load_bvh

    files = sorted(Path(args.bvh_dir).glob("*.bvh"))
    if not files:
        sys.exit(f"no .bvh files in {args.bvh_dir}")
    garments = args.garment or ["default"]
    can_clear = "clear_arms" in {f.name for f in dataclasses.fields(Motion)}
    variants = [("as recorded", False if can_clear else None)] + ([("arms turned out", True)] if can_clear else [])
    draper = Draper()
    load = os.getloadavg()
    table, rows_out = [], {}
    for garment in garments:
        for label, clear in variants:
            rows = []
            for path in files:
                frames = list(range(0, load_bvh(path).num_frames, args.stride))
                rows += drape_frames(draper, Motion, path, frames, garment, clear)
                print(f"{garment} / {label}: {path.name} done", flush=True)
            rows_out[f"{garment} / {label}"] = rows
            table.append((garment, label, summary(rows)))
    command, prov, lines = page_head("Motion-capture frames draped one by one")
    end = os.getloadavg()
    record = {"command": command, **prov, "stride": args.stride, "files": [f.name for f in files],
              "load_average_start": load, "load_average_end": end, "torn_above_J": TORN_J,
              "summary": [{"garment": g, "variant": v, **s} for g, v, s in table], "frames": rows_out}

    def f(value, spec: str) -> str:
        return "–" if value is None else format(value, spec)

    lines += [f"Every {args.stride}th frame of {', '.join(record['files'])}, each draped on its own (bundled "
              f"model, T = 15, one torch thread); load average {load[0]:.2f} at the start, {end[0]:.2f} at the end. "
              f"Refused: the arms pass through the torso (`Draper(check_pose=True)`). Torn: E_strain above "
              f"{TORN_J:g} J (a draped T-shirt holds about 0.01–0.1 J). Inside: B2G > 0. Turned: frames whose arms "
              "were turned out at the shoulders (`body/arm_clearance.py`), and the median and largest turn of "
              "their more-turned arm.", "",
              "| garment | arms | frames | refused | draped | inside | torn | median E_strain [J] | largest "
              "E_strain [J] | mean B2G [%] | largest B2G [%] | turned | median turn [deg] | largest turn [deg] |",
              "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for garment, label, s in table:
        lines.append(f"| {garment} | {label} | {s['frames']} | {s['refused']} | {s['draped']} | {s['inside']} | "
                     f"{s['torn']} | {f(s['median_strain_J'], '.4f')} | {f(s['max_strain_J'], '.3g')} | "
                     f"{f(s['mean_b2g_percent'], '.3f')} | {f(s['max_b2g_percent'], '.3g')} | {s['turned']} | "
                     f"{f(s['median_turn_deg'], '.0f')} | {f(s['max_turn_deg'], '.0f')} |")
    write_report(args.out, lines, record)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

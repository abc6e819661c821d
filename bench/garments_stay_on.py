"""Do real multi-piece garments stay where they are worn? The five CC0 MakeHuman suits (and any
other garment specs, e.g. generated trousers and outfits) on three seeded bodies from slim to
heavy, draped through the public API.

Run: .venv/bin/python bench/garments_stay_on.py [--suits ../shared/data/makehuman_cc0 | --no-suits]
     [--garment SPEC]... [--variant NAME:KEY=VALUE,...]... [--steps 15] [--threads 1]
     [--out results/garments_stay_on] [--render-variant NAME] [--render-size 360]

Each suit (`.mhclo`, or a `--garment` spec: `trousers:0`, `outfit:2`, a file) × body is one
`Draper.drape(spec, shape=..., pose=...)` call per
variant; a variant is a name and keyword arguments of `Draper.drape` (e.g. ``fixed:sizing=fixed``;
values are parsed as JSON where they parse, else kept as text). The bodies: phenotypes drawn
from a seeded generator in [0.25, 0.75] with weight set to 0.1 (slim), 0.5 and 0.9 (heavy); poses
``relaxed`` (the default), ``random:2`` and ``relaxed``. Per drape (definitions also written into
the outputs):

- ``waist_drop_cm``: mean over the lower piece's waistband vertices of y_init − y [cm]
  (`garments.pieces`; positive = the trousers slid down from X_init); ``waist_top_drop_cm`` the
  same for the waistband's highest vertex at X_init;
- ``hem_rise_cm``: mean over the top's hem vertices of y − y_init [cm] (positive = rode up);
- ``band_cm``: the widest band of skin between the top's hem and the trousers' waistband: around
  the waistband's centre in 24 azimuth sectors, max over sectors of max(0, lowest hem y − highest
  waistband y) [cm]; ``band_canonical_cm`` the same on the template on the canonical body,
  ``band_canonical_pose_cm`` on the same garment draped (the same variant) on the canonical body
  in the same pose (a raised arm lifts a top on any body: what sizing must keep is the band the
  garment has on the body it was made for); ``band_scaled_cm`` the band times the canonical
  body's height over this body's (in the same pose): a garment worn at the same place on a
  taller body bares a proportionally wider band;
- ``front_gap_mm``: where the template's panels overlap (`garments.closures.panel_overlaps` on the
  template, the trousers excluded), how far the paired vertices have parted beyond their distance
  on the template, max(0, d − d_template), mean and largest over the pairs [mm]
  (``front_gap_init_mm``: at X_init; ``front_gap_template_mm``: the mean pair distance on the template);
- ``b2g_percent``: the drape's B2G % (`physics.metrics`);
- ``piece_x_init``, ``piece_x``: face pairs of different pieces that intersect at X_init and in
  the drape (`geometry.intersections`); ``piece_x_new`` = max(0, drape − X_init).

Writes <out>.json and <out>.md atomically, each naming the command and the git commit, and front
and back renders of every drape of --render-variant (default the last variant) as
<out>/<suit>_<body>.png.
"""

from __future__ import annotations

import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch

from physdrape.api import Draper
from physdrape.atomic import write_text
from physdrape.body.anny_body import PHENOTYPE_NAMES
from physdrape.eval.report import finite_or_none
from physdrape.garments.closures import panel_overlaps
from physdrape.garments.pieces import garment_parts
from physdrape.geometry.intersections import piece_crossings
from physdrape.provenance import provenance

BODIES = (("slim", 0.1, "relaxed"), ("average", 0.5, "random:2"), ("heavy", 0.9, "relaxed"))
SECTORS = 24
DEFINITIONS = {
    "waist_drop_cm": "mean over the lower piece's waistband vertices of y_init - y [cm]; positive = slid down",
    "waist_top_drop_cm": "y_init - y of the waistband vertex highest at X_init [cm]",
    "hem_rise_cm": "mean over the top's hem vertices of y - y_init [cm]; positive = rode up",
    "band_cm": "widest skin band between the top's hem and the waistband: max over 24 azimuth sectors about the "
               "waistband's centre of max(0, lowest hem y - highest waistband y) [cm]",
    "band_canonical_cm": "the same on the template on the canonical body [cm]",
    "band_canonical_pose_cm": "the same in the drape (same variant) on the canonical body in the same pose [cm]",
    "band_scaled_cm": "band_cm x (canonical body's height / this body's height), both in the same pose [cm]",
    "band_init_cm": "the same at X_init [cm]",
    "front_gap_mm": "where the template's panels overlap (vertex pairs of garments.closures.panel_overlaps, trousers "
                    "excluded): how far the pairs have parted beyond their distance on the template, "
                    "max(0, d - d_template), mean and largest over the pairs [mm], in the drape",
    "front_gap_init_mm": "the same at X_init",
    "front_gap_template_mm": "the mean distance of the pairs on the template [mm]",
    "b2g_percent": "area share of faces whose centroid is inside the body [%]",
    "piece_x_init, piece_x": "intersecting face pairs between different pieces at X_init and in the drape",
    "piece_x_new": "max(0, piece_x - piece_x_init)",
}


def body_shapes(seed: int = 0) -> list[dict]:
    """The three bodies' phenotypes: seeded draws in [0.25, 0.75], weight slim → heavy."""
    rng = np.random.default_rng(seed)
    out = []
    for _, weight, _ in BODIES:
        values = dict(zip(PHENOTYPE_NAMES, rng.uniform(0.25, 0.75, len(PHENOTYPE_NAMES)).round(3).tolist()))
        values["weight"] = weight
        out.append(values)
    return out


def skin_band(x: np.ndarray, hem: np.ndarray | None, waistband: np.ndarray | None) -> float | None:
    """Widest band of skin between hem and waistband [m] (module docstring), or None."""
    if hem is None or waistband is None:
        return None
    centre = x[waistband][:, [0, 2]].mean(0)

    def sector(ids):
        d = x[ids][:, [0, 2]] - centre
        return (np.floor((np.arctan2(d[:, 0], d[:, 1]) + np.pi) / (2 * np.pi) * SECTORS).astype(int)) % SECTORS

    low = np.full(SECTORS, np.inf)
    np.minimum.at(low, sector(hem), x[hem, 1])
    high = np.full(SECTORS, -np.inf)
    np.maximum.at(high, sector(waistband), x[waistband, 1])
    both = np.isfinite(low) & np.isfinite(high)
    return float(np.clip(low[both] - high[both], 0.0, None).max()) if both.any() else None


def body_height(body_verts: np.ndarray) -> float:
    """The posed body's vertical extent [m]."""
    y = np.asarray(body_verts, np.float64)[:, 1]
    return float(y.max() - y.min())


def pair_gaps(x: np.ndarray, pairs: np.ndarray, reference: np.ndarray | None = None) -> tuple[float | None, float | None]:
    """Mean and largest distance between paired vertices [m] beyond their distance in
    `reference` (None: the plain distance), or (None, None) without pairs."""
    if len(pairs) == 0:
        return None, None
    d = np.linalg.norm(x[pairs[:, 0]] - x[pairs[:, 1]], axis=1)
    if reference is not None:
        d = np.clip(d - np.linalg.norm(reference[pairs[:, 0]] - reference[pairs[:, 1]], axis=1), 0.0, None)
    return float(d.mean()), float(d.max())


def measure(res, template, parts, overlaps) -> dict:
    x, x0, faces = np.asarray(res.verts, np.float64), np.asarray(res.x_init, np.float64), template.faces
    row: dict = {}
    if parts.waistband is not None:
        wb = parts.waistband
        row["waist_drop_cm"] = 100 * float((x0[wb, 1] - x[wb, 1]).mean())
        top = wb[np.argmax(x0[wb, 1])]
        row["waist_top_drop_cm"] = 100 * float(x0[top, 1] - x[top, 1])
    if parts.hem is not None:
        row["hem_rise_cm"] = 100 * float((x[parts.hem, 1] - x0[parts.hem, 1]).mean())
    for key, pos in (("band_cm", x), ("band_init_cm", x0)):
        band = skin_band(pos, parts.hem, parts.waistband)
        row[key] = None if band is None else 100 * band
    for key, pos in (("front_gap", x), ("front_gap_init", x0)):
        mean, top = pair_gaps(pos, overlaps, template.verts)
        row[f"{key}_mm"] = None if mean is None else 1000 * mean
        row[f"{key}_max_mm"] = None if top is None else 1000 * top
    row["b2g_percent"] = res.metrics["b2g_percent"]
    row["piece_x_init"] = piece_crossings(x0, faces, parts.piece)
    row["piece_x"] = piece_crossings(x, faces, parts.piece)
    row["piece_x_new"] = max(0, row["piece_x"] - row["piece_x_init"])
    row["E_strain_J"], row["E_bend_J"] = res.metrics["strain"], res.metrics["bend"]
    return row


def parse_variant(text: str) -> tuple[str, dict]:
    name, _, rest = text.partition(":")
    if not name:
        raise SystemExit(f"--variant {text!r}: give NAME or NAME:KEY=VALUE,...")
    kwargs = {}
    for item in filter(None, rest.split(",")):
        key, eq, value = item.partition("=")
        if not eq:
            raise SystemExit(f"--variant {text!r}: {item!r} is not KEY=VALUE")
        try:
            kwargs[key] = json.loads(value)
        except json.JSONDecodeError:
            kwargs[key] = value
    return name, kwargs


def fmt(value, digits: int = 2) -> str:
    return "–" if value is None else f"{value:.{digits}f}"


def markdown(record: dict) -> str:
    lines = ["# Garments stay where they are worn: multi-piece and lower-body garments on slim to heavy bodies", "",
             f"Command: `{record['command']}`  ", f"Git commit: `{record['provenance']['git_commit']}`"
             + (" (with uncommitted changes)" if record["provenance"]["git_dirty"] else ""), "",
             f"`Draper.drape(garment, shape=..., pose=...)`, T = {record['config']['steps']}, torch threads "
             f"{record['config']['threads']}. Bodies (phenotypes {', '.join(PHENOTYPE_NAMES)}):", ""]
    for (label, _, pose), shape in zip(BODIES, record["bodies"]):
        lines.append(f"- **{label}**: {', '.join(f'{k} {v:g}' for k, v in shape.items())}; pose `{pose}`")
    lines += ["", "Definitions:", ""] + [f"- **{k}**: {v}" for k, v in DEFINITIONS.items()] + [""]
    lines += ["## Summary per variant", "",
              "| variant | drape kwargs | waist drop mean [cm] | waist drop max [cm] | hem rise max [cm] | band > canonical "
              "+ 0.5 cm | band > canonical body in the pose + 0.5 cm | band scaled to the canonical height > canonical "
              "body in the pose + 0.5 cm | band > X_init + 0.5 cm | front gap mean [mm] | front gap max [mm] | B2G max [%] "
              "| piece crossings X_init → drape (sum) | new piece crossings (sum) | wall [s] |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for v in record["variants"]:
        rows = v["rows"]

        def col(key, rows=rows):
            return [r[key] for r in rows if r.get(key) is not None]

        over = sum(1 for r in rows if r.get("band_cm") is not None and r["band_cm"] > r["band_canonical_cm"] + 0.5)
        over_init = sum(1 for r in rows if r.get("band_cm") is not None and r["band_cm"] > r["band_init_cm"] + 0.5)
        over_pose = sum(1 for r in rows if r.get("band_cm") is not None
                        and r["band_cm"] > r["band_canonical_pose_cm"] + 0.5)
        over_scaled = sum(1 for r in rows if r.get("band_cm") is not None
                          and r["band_scaled_cm"] > r["band_canonical_pose_cm"] + 0.5)
        lines.append(f"| {v['name']} | `{json.dumps(v['kwargs'])}` | {fmt(np.mean(col('waist_drop_cm')))} | "
                     f"{fmt(max(col('waist_drop_cm')))} | {fmt(max(col('hem_rise_cm')))} | {over} / {len(rows)} | "
                     f"{over_pose} / {len(rows)} | {over_scaled} / {len(rows)} | "
                     f"{over_init} / {len(rows)} | "
                     f"{fmt(np.mean(col('front_gap_mm')) if col('front_gap_mm') else None, 1)} | "
                     f"{fmt(max(col('front_gap_max_mm')) if col('front_gap_max_mm') else None, 1)} | "
                     f"{fmt(max(col('b2g_percent')))} | {sum(col('piece_x_init'))} → {sum(col('piece_x'))} | "
                     f"{sum(col('piece_x_new'))} | {fmt(v['wall_s'], 0)} |")
    for v in record["variants"]:
        lines += ["", f"## {v['name']}", "",
                  "| suit | body | waist drop [cm] | top drop [cm] | hem rise [cm] | band [cm] (init, canonical, canonical "
                  "body in the pose; scaled to the canonical height) | "
                  "front gap mean / max [mm] (init) | B2G [%] | piece crossings init → drape | E_strain [J] |",
                  "|---|---|---|---|---|---|---|---|---|---|"]
        for r in v["rows"]:
            lines.append(
                f"| {r['suit']} | {r['body']} | {fmt(r.get('waist_drop_cm'))} | {fmt(r.get('waist_top_drop_cm'))} | "
                f"{fmt(r.get('hem_rise_cm'))} | {fmt(r.get('band_cm'))} ({fmt(r.get('band_init_cm'))}, "
                f"{fmt(r.get('band_canonical_cm'))}, {fmt(r.get('band_canonical_pose_cm'))}; "
                f"{fmt(r.get('band_scaled_cm'))}) | {fmt(r.get('front_gap_mm'), 1)} / {fmt(r.get('front_gap_max_mm'), 1)} "
                f"({fmt(r.get('front_gap_init_mm'), 1)} / {fmt(r.get('front_gap_init_max_mm'), 1)}) | "
                f"{fmt(r['b2g_percent'])} | {r['piece_x_init']} → {r['piece_x']} | {r['E_strain_J']:.3g} |")
    lines += ["", "Panel overlaps found on each template (vertex pairs; mean distance on the template):", ""]
    for name, info in record["templates"].items():
        lines.append(f"- {name}: {info['num_verts']} vertices, {info['num_pieces']} pieces, {info['overlaps']} "
                     f"pairs ({fmt(info['front_gap_template_mm'], 1)} mm)")
    if record.get("renders"):
        lines += ["", f"Renders (front and back) of variant `{record['render_variant']}`: "
                  + ", ".join(f"`{p}`" for p in record["renders"])]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suits", type=Path, default=Path("../shared/data/makehuman_cc0"))
    parser.add_argument("--no-suits", action="store_true", help="only the --garment specs")
    parser.add_argument("--garment", action="append", default=[],
                        help="a garment spec of Draper.drape to measure too (repeatable), e.g. trousers:0, outfit:2")
    parser.add_argument("--variant", action="append", default=None,
                        help="NAME:KEY=VALUE,... keyword arguments of Draper.drape (repeatable; default 'default:')")
    parser.add_argument("--steps", type=int, default=15)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--out", type=Path, default=Path("results/garments_stay_on"))
    parser.add_argument("--render-variant", default=None)
    parser.add_argument("--render-size", type=int, default=360)
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    command = "python " + shlex.join(sys.argv if argv is None else ["bench/garments_stay_on.py", *argv])
    suits = [] if args.no_suits else [str(p) for p in sorted(args.suits.glob("*/*.mhclo"))]
    if not suits and not args.no_suits:
        raise SystemExit(f"no .mhclo files under {args.suits}/*/: give --suits DIR (the CC0 MakeHuman suits)")
    suits += args.garment
    if not suits:
        raise SystemExit("nothing to drape: give --garment SPEC with --no-suits")
    variants = [parse_variant(v) for v in (args.variant or ["default:"])]
    render_variant = args.render_variant or variants[-1][0]
    shapes = body_shapes(args.seed)
    draper = Draper(steps=args.steps)
    templates, info = {}, {}
    for path in suits:
        t = draper.garment(path)
        parts = garment_parts(t.verts, t.faces)
        exclude = parts.piece == parts.lower if parts.lower is not None else None
        overlaps = panel_overlaps(t.verts, t.faces, parts.piece, exclude=exclude)
        templates[path] = (t, parts, overlaps)
        band = skin_band(t.verts, parts.hem, parts.waistband)
        info[t.name] = {"num_verts": t.num_verts, "num_pieces": parts.num_pieces, "overlaps": len(overlaps),
                        "front_gap_template_mm": None if not len(overlaps) else 1000 * pair_gaps(t.verts, overlaps)[0],
                        "band_canonical_cm": None if band is None else 100 * band}
    record = {"command": command, "provenance": provenance(), "config": {k: str(v) for k, v in vars(args).items()},
              "bodies": shapes, "definitions": DEFINITIONS, "templates": info, "variants": [],
              "render_variant": render_variant, "renders": []}
    render_dir = args.out
    for name, kwargs in variants:
        rows, t_start = [], time.perf_counter()
        for path in suits:
            t, parts, overlaps = templates[path]
            canonical_band, canonical_height = {}, {}  # per pose, on the canonical body: band [cm], height [m]
            for pose in sorted({pose for _, _, pose in BODIES}):
                [res] = draper.drape(path, shape=None, pose=pose, **kwargs)
                band = skin_band(np.asarray(res.verts, np.float64), parts.hem, parts.waistband)
                canonical_band[pose] = None if band is None else 100 * band
                canonical_height[pose] = body_height(res.body_verts)
            for (label, _, pose), shape in zip(BODIES, shapes):
                t0 = time.perf_counter()
                [res] = draper.drape(path, shape=shape, pose=pose, **kwargs)
                row = {"suit": t.name, "body": label, "pose": pose, "drape_s": time.perf_counter() - t0}
                row.update(measure(res, t, parts, overlaps))
                row["band_canonical_cm"] = info[t.name]["band_canonical_cm"]
                row["band_canonical_pose_cm"] = canonical_band[pose]
                row["body_height_m"] = body_height(res.body_verts)
                row["band_scaled_cm"] = (None if row.get("band_cm") is None
                                         else row["band_cm"] * canonical_height[pose] / row["body_height_m"])
                rows.append(row)
                print(f"[{name}] {t.name} {label}: waist drop {fmt(row.get('waist_drop_cm'))} cm, band "
                      f"{fmt(row.get('band_cm'))} cm, front gap {fmt(row.get('front_gap_mm'), 1)} mm, B2G "
                      f"{row['b2g_percent']:.2f} %, piece crossings {row['piece_x_init']} → {row['piece_x']} "
                      f"({row['drape_s']:.0f} s)", flush=True)
                if name == render_variant:
                    png = render_dir / f"{t.name}_{label}.png"
                    render_dir.mkdir(parents=True, exist_ok=True)
                    res.render(png, size=args.render_size)
                    record["renders"].append(str(png))
        record["variants"].append({"name": name, "kwargs": kwargs, "rows": rows,
                                   "wall_s": time.perf_counter() - t_start})
    out = args.out
    write_text(out.with_suffix(".json"), json.dumps(finite_or_none(record), indent=1, allow_nan=False, default=str) + "\n")
    write_text(out.with_suffix(".md"), markdown(record))
    print(markdown(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())

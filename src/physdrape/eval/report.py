"""The evaluation's record: Markdown tables of the results and the
atomic writing of ``eval.json`` / ``eval.md`` (the protocol itself is `physdrape.eval.evaluate`)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

from physdrape.atomic import write_text

#: Context only: the paper's numbers (CLOTH3D garments, SMPL bodies) — different data from ours.
PUBLISHED_NOTE = "published, CLOTH3D/SMPL — different data"
PUBLISHED_MAIN = [
    {"method": "DeePSD", "strain": 7.22, "bend": 0.01, "b2g_percent": 7.2},
    {"method": "DIG", "strain": 6.32, "bend": 0.01, "b2g_percent": 1.8},
    {"method": "DrapeNet", "strain": 0.43, "bend": 0.01, "b2g_percent": 0.9},
    {"method": "PhysDrape (T=3)", "strain": 0.20, "bend": 0.004, "b2g_percent": 0.05},
    {"method": "PhysDrape (T=15)", "strain": 0.15, "bend": 0.004, "b2g_percent": 0.05},
]
PUBLISHED_ABLATION = [
    {"method": "GNN", "strain": 0.20, "bend": 0.004, "b2g_percent": 3.50},
    {"method": "GNN + solver", "strain": 0.17, "bend": 0.003, "b2g_percent": 2.29},
    {"method": "GNN + collision", "strain": 0.21, "bend": 0.004, "b2g_percent": 0.06},
    {"method": "GNN + solver + collision (full)", "strain": 0.15, "bend": 0.004, "b2g_percent": 0.05},
]


def _fmt(value, digits: int = 3) -> str:
    if value is None or (isinstance(value, float) and not math.isfinite(value)):
        return "–"
    if isinstance(value, float):
        if value != 0 and (abs(value) < 10 ** -digits or abs(value) >= 1e4):
            return f"{value:.{digits - 1}e}"
        return f"{value:.{digits}g}" if abs(value) < 1 else f"{value:.{digits}f}".rstrip("0").rstrip(".")
    return str(value)


def _table(rows: list[tuple[str, dict]], *, timing: bool, oracle: bool) -> list[str]:
    head = ["Method", "E_strain [J]", "E_bend [J]", "B2G %", "close %", "residual [N]", "E_total [J]"]
    crossings = any("piece_crossings" in s for _, s in rows)  # a set of garments worn in pieces
    if crossings:
        head += ["piece crossings (sum)"]
    if oracle:
        head += ["E_strain / reference", "E_bend / reference", "E_total / reference"]
    if timing:
        head += ["wall / garment [s] (mean)"]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, s in rows:
        cells = [label] + [_fmt(s.get(k)) for k in ("strain", "bend", "b2g_percent", "close_percent", "residual_force", "energy_total")]
        if crossings:
            cells += [_fmt(s.get("piece_crossings"))]
        if oracle:
            cells += [_fmt(s.get(f"{k}_ratio")) for k in ("strain", "bend", "energy_total")]
        if timing:
            cells += [_fmt(s.get("wall_s"))]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _group_table(rows: list[tuple[str, str]], data: dict, groups: str) -> list[str]:
    """Rows × the groups of data[groups] ("categories": garment categories, "poses": pose indices):
    each row's mean E_total over the group's instances over the reference's mean over them (the
    column "all": over every instance)."""
    table = data[groups]
    head = ["Method", f"all ({len(data['instances'])})"] + [f"{g} ({len(v['instances'])})" for g, v in table.items()]
    lines = ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for label, key in rows:
        overall = (data[key] if key in data else data["rows"][key])["summary"]
        cells = [label, _fmt(overall.get("energy_total_ratio"))]
        cells += [_fmt(v["rows"][key]["energy_total_ratio"]) for v in table.values()]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


#: (T, the full model's row, the same solver without the network)
NETWORK_PAIRS = ((3, "physdrape_t3", "physics_only_t3"), (15, "physdrape_t15", "physics_only"))


def _network_table(data: dict) -> list[str]:
    """What the network adds at each T: the full model's E_total and E_strain over the reference's
    beside the network-free solver's (the same solver and handler, Δx = 0, f̂ = 0), and the
    difference (negative: the network lowers the energy)."""
    head = ("| T | E_total / reference: PhysDrape | solver alone | network's share | "
            "E_strain / reference: PhysDrape | solver alone | network's share |")
    lines = [head, "|---|---:|---:|---:|---:|---:|---:|"]
    for steps, model, alone in NETWORK_PAIRS:
        if model not in data["rows"] or alone not in data["rows"]:
            continue
        a, b = data["rows"][model]["summary"], data["rows"][alone]["summary"]
        cells = [str(steps)]
        for key in ("energy_total_ratio", "strain_ratio"):
            x, y = a.get(key), b.get(key)
            cells += [_fmt(x), _fmt(y), f"{x - y:+.3f}" if x is not None and y is not None and math.isfinite(x - y) else "–"]
        lines.append("| " + " | ".join(cells) + " |")
    return lines


def _published(rows: list[dict]) -> list[str]:
    lines = [f"| Method ({PUBLISHED_NOTE}) | E_strain | E_bend | B2G % |", "|---|---|---|---|"]
    lines += [f"| {r['method']} | {r['strain']} | {r['bend']} | {r['b2g_percent']} |" for r in rows]
    return lines


def render_markdown(results: dict, *, timing: bool = True) -> str:
    """Both tables (per instance set) as Markdown; timing=False leaves the wall-time columns out
    (everything else is deterministic for a seed)."""
    cfg = results["config"]
    has_oracle = bool(cfg["oracle"])
    out = ["# PhysDrape evaluation", ""]
    ck = results["checkpoints"]["physdrape_t15"]
    test = results["sets"]["test"]["instances"]
    poses = max(i.get("pose_index", 0) for i in test) + 1 if test else 0
    passes = ck.get("passes", 1)
    looks = "one network pass" if passes == 1 else (f"{passes} network passes, each reading its inputs at the garment "
                                                     "the passes before it moved")
    out.append(f"Checkpoint: `{ck['path']}` (step {ck['step']}; {looks}). Seed {cfg['seed']}, {len(test)} test "
               f"instances ({len({i['garment'] for i in test})} test garments, up to {poses} pose(s) each; instance "
               f"i: garment i mod G in pose i div G, on a body drawn from its own seed), default material, dtype "
               f"{cfg['dtype']}.")
    if timing:
        out.append(f"Command: `{results['command']}`")
    out.append("")
    out.append("Rows (all from the one checkpoint, switched at inference):")
    for d in results["row_definitions"].values():
        out.append(f"- **{d['label']}**: {d['definition']}" + (f" (T = {d['steps']})" if d["steps"] else ""))
    out.append("- **X_init**: the kinematic initialisation every row starts from (skinning transfer, then contact-aware "
               "strain limiting of the edges to 1.02 x rest; a multi-piece garment's outer pieces then pushed out over "
               "the inner ones), for context. Every model row's wall time includes it.")
    out.append("- **Skinned**: the skinning transfer with only the local limit of its artefacts (edges ≤ 1.5 x rest): "
               "where the oracle starts (a classical solver gets the plain kinematic start, not PhysDrape's pull-back).")
    if has_oracle:
        out.append(f"- **Oracle**: {results['oracle_definition']}.")
    settle = cfg.get("oracle_settle_steps", 0) if has_oracle else 0
    if cfg.get("oracle_refine") and has_oracle:
        out.append("- **Oracle refining PhysDrape (T=15)**: the oracle started from the model's drape (the refinement "
                   "mode); its wall time includes the model's.")
    if settle:
        out.append(f"- **Oracle from PhysDrape (T={settle})**: the oracle started from the model's drape at T = "
                   f"{settle}, settled further along the slow modes (the oracle stops in the equilibrium its start "
                   "leads to); its wall time includes the model's.")
    if has_oracle and (cfg.get("oracle_refine") or settle):
        out.append("- **Reference**: per instance the lowest-E_total of the oracle results that converged (none: of "
                   "all), the best equilibrium found from any start.")
    out.append("")
    out.append("Energies are means over instances under the default material; E_total = E_strain + E_bend + E_grav + "
               "contact penalty (what the oracle minimises), plus, for the MakeHuman garments, worn as `Draper.drape` "
               "wears an .mhclo (sized to fit, waistband gripped, closures stitched, pieces kept in their layer "
               "order), the grip, stitch and layer-order terms (the template's layer pairs completed by those "
               "found where the pieces are, as the oracle minimises it: `physics.layers.follow_pairs`); their "
               "piece crossings: the face pairs of two different pieces that intersect, summed over the "
               "instances (the energy does not see a piece that is already through another). Ratios: row mean / "
               "reference "
               "mean on the same instances. residual: mean |F_int| over vertices > 3 mm from the body. The oracle's "
               "wall time is a lower bound where it stopped on its budget instead of converging.")
    cache = results.get("reference_cache")
    if timing and cache and cache["hits"]:
        out.append("")
        out.append(f"{cache['hits']} of the oracle runs from the skinned start were read from the reference cache "
                   f"(`{cache['dir']}`): the same instance, settings and code version; their wall times are those of "
                   "the run that computed them.")
    for set_name, data in results["sets"].items():
        oracle = data["oracle"]["summary"] if data["oracle"] else None
        title = "test garments × seeded Anny shapes/poses" if set_name == "test" else "CC0 MakeHuman garments"
        out += ["", f"## Table 1 — {title} ({len(data['instances'])} instances)", ""]
        rows = [(results["row_definitions"][k]["label"], data["rows"][k]["summary"]) for k in results["row_definitions"]]
        if "x_init" in data:
            rows.insert(0, ("X_init (kinematic start, no model; context)", data["x_init"]["summary"]))
        if "skinned" in data:
            rows.insert(0, ("Skinned (the oracle's start; context)", data["skinned"]["summary"]))
        n = len(data["instances"])
        if oracle:
            rows.append((f"Oracle from the skinned start ({oracle['converged']}/{n} converged)", oracle))
        if data.get("oracle_refined"):
            refined = data["oracle_refined"]["summary"]
            rows.append((f"Oracle refining PhysDrape (T=15) ({refined['converged']}/{n} converged)", refined))
        if data.get("oracle_settled"):
            settled = data["oracle_settled"]["summary"]
            rows.append((f"Oracle from PhysDrape (T={settle}) ({settled['converged']}/{n} converged)", settled))
        if data.get("oracle_refined") or data.get("oracle_settled"):
            reference = data["reference"]["summary"]
            sources = [f"{reference['from_refinement']}/{n} from the refinement"] if data.get("oracle_refined") else []
            if data.get("oracle_settled"):
                sources.append(f"{reference['from_settled']}/{n} from T={settle}")
            rows.append((f"Reference (lowest E_total of the converged per instance; {', '.join(sources)})", reference))
        out += _table(rows, timing=timing, oracle=has_oracle)
        if data.get("categories") and data.get("reference"):
            keyed = ([("Skinned", "skinned")] if "skinned" in data else []) + [("X_init", "x_init")]
            keyed += [(results["row_definitions"][k]["label"], k) for k in results["row_definitions"]]
            keyed += [(label, key) for label, key in (("Oracle from the skinned start", "oracle"),
                                                      ("Oracle refining PhysDrape (T=15)", "oracle_refined"),
                                                      (f"Oracle from PhysDrape (T={settle})", "oracle_settled"))
                      if data.get(key)]
            out += ["", ("E_total / reference by garment category (row mean over the category's instances over the "
                         "reference's mean over them; instances in brackets):"), ""]
            out += _group_table(keyed, data, "categories")
            if data.get("poses"):
                out += ["", ("E_total / reference by pose (each garment's k-th seeded body; row mean over the "
                             "pose's instances over the reference's mean over them):"), ""]
                out += _group_table(keyed, data, "poses")
        if data.get("reference"):
            out += ["", ("What the network adds (the full model's ratios minus those of the same solver and handler "
                         "without the network):"), ""]
            out += _network_table(data)
        sources = {d["source"] for d in results["ablation_definitions"].values()}
        if sources == {"switched"}:
            how = "switched at inference on the full model, not retrained"
        elif sources == {"retrained"}:
            how = "separately trained checkpoints, one per variant"
        else:
            how = "mixed: rows marked (switched) are switched at inference on the full model, not retrained"
        out += ["", f"## Table 2 — module ablation ({how})", ""]
        rows = []
        for k, d in results["ablation_definitions"].items():
            mark = " (switched)" if d["source"] == "switched" and sources != {"switched"} else ""
            steps = f", T = {d['steps']}" if d["steps"] else ""
            rows.append((f"{d['label']}{mark}{steps}", data["rows"][f"ablation:{k}"]["summary"]))
        out += _table(rows, timing=timing, oracle=has_oracle)
    out += ["", "## Context: published numbers (not comparable)", "",
            f"Table 1 of the paper — {PUBLISHED_NOTE}:", ""] + _published(PUBLISHED_MAIN)
    out += ["", f"Table 2 of the paper — {PUBLISHED_NOTE}:", ""] + _published(PUBLISHED_ABLATION)
    if results.get("notes"):
        out += ["", "Notes:"] + [f"- {n}" for n in results["notes"]]
    return "\n".join(out) + "\n"


def finite_or_none(value):
    """`value` with every NaN/inf float, in nested dicts, lists and tuples, as None (strict JSON)."""
    if isinstance(value, dict):
        return {k: finite_or_none(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [finite_or_none(v) for v in value]
    if isinstance(value, float) and not math.isfinite(value):
        return None
    return value


def write_results(results: dict, out_dir: str | os.PathLike, *, stem: str = "eval") -> tuple[Path, Path]:
    """Write `<stem>.json` (every number) and `<stem>.md` (the tables) atomically into out_dir."""
    out_dir = Path(out_dir)
    json_path, md_path = out_dir / f"{stem}.json", out_dir / f"{stem}.md"
    write_text(json_path, json.dumps(finite_or_none(results), indent=1, allow_nan=False) + "\n")
    write_text(md_path, render_markdown(results))
    return json_path, md_path

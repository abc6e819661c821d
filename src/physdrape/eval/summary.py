"""Means over instances: per row, per garment category, and the ratios to the reference."""

from __future__ import annotations

import math

import numpy as np

from physdrape.eval.instances import CATEGORIES

METRIC_KEYS = ("strain", "bend", "b2g_percent", "close_percent", "residual_force", "residual_relative", "energy_total")
#: The energies given as a ratio of a row's mean to the reference's mean over the same instances.
RATIO_KEYS = ("strain", "bend", "energy_total")
#: What the per-category summaries hold (means over the category's instances, and ratios).
CATEGORY_KEYS = ("strain", "energy_total", "b2g_percent")


def summary(records: list[dict]) -> dict:
    """Mean of every metric and of the wall time over `records`, and the median wall time; the
    piece crossings summed, where any record counts them (a set with garments of several pieces;
    a garment of one piece counts none)."""
    out = {}
    for key in METRIC_KEYS + ("wall_s",):
        values = [r[key] for r in records]
        out[key] = float(np.mean(values)) if values else math.nan
    out["wall_s_median"] = float(np.median([r["wall_s"] for r in records])) if records else math.nan
    if any("piece_crossings" in r for r in records):
        out["piece_crossings"] = int(sum(r.get("piece_crossings", 0) for r in records))
    return out


def with_ratios(summary: dict, reference: dict | None) -> dict:
    """Adds `<key>_ratio` for the energies of RATIO_KEYS: the summary's mean over the reference's
    mean over the same instances (NaN without a reference or when its mean is 0)."""
    for key in RATIO_KEYS:
        ref = reference[key] if reference else math.nan
        summary[f"{key}_ratio"] = summary[key] / ref if reference and ref != 0 else math.nan
    return summary


def oracle_summary(records: list[dict]) -> dict:
    """`summary` plus how many runs converged, the largest final residual, and how many results
    came from the reference cache."""
    out = summary(records)
    out["converged"] = sum(r["converged"] for r in records)
    out["oracle_residual_max"] = max(r["oracle_residual"] for r in records)
    out["cached"] = sum(bool(r.get("cached")) for r in records)
    return out


def reference(oracle: list[dict], refined: list[dict], settled: list[dict] | None = None) -> list[dict]:
    """Per instance the converged oracle result with the lowest E_total (none converged: the
    lowest of all; ties: the earlier of oracle, refined, settled), tagged with its source
    ("oracle", "oracle_refined" or "oracle_settled"); an empty list of results is left out
    (without either, the oracle's own records). A run stopped on its budget can end lower in a
    state that is no equilibrium (a collapsed element's force unbounded at a finite energy), so
    an equilibrium the oracle reached comes first."""
    candidates = [("oracle", oracle), *((name, recs) for name, recs in (("oracle_refined", refined),
                                                                        ("oracle_settled", settled or [])) if recs)]
    for name, recs in candidates[1:]:
        if len(recs) != len(oracle):
            raise ValueError(f"{name} has {len(recs)} records for {len(oracle)} instances")
    out = []
    for i in range(len(oracle)):
        name, best = lowest_converged([(name, recs[i]) for name, recs in candidates])
        out.append({**best, "source": name})
    return out


def lowest_converged(results: list[tuple[str, dict]]) -> tuple[str, dict]:
    """Of (name, record) oracle results of one instance, the converged one with the lowest
    "energy_total" (none converged: the lowest of all; ties: the earlier; a record without
    "converged" counts as converged): `reference`'s rule for one instance."""
    if not results:
        raise ValueError("no oracle results to choose a reference from")
    converged = [c for c in results if c[1].get("converged", True)]
    return min(converged or results, key=lambda c: c[1]["energy_total"])


def by_category(categories: list[str | None], rows: dict[str, list[dict]], ref: list[dict] | None) -> dict:
    """Per garment category (those of CATEGORIES present, in that order): the instances in it and,
    for every row of `rows` ({key: per-instance records, in instance order}), the means of
    CATEGORY_KEYS over them and their ratios to the reference's means over the same instances.
    Instances of no category (MakeHuman garments) are in none; no categories: {}."""
    return _by_group(categories, CATEGORIES, rows, ref)


def by_pose(poses: list[int], rows: dict[str, list[dict]], ref: list[dict] | None) -> dict:
    """The same per pose index ("pose 0", "pose 1", ...: each garment's k-th seeded body), when the
    instances hold more than one pose; else {}."""
    found = sorted(set(poses))
    return _by_group([f"pose {p}" for p in poses], [f"pose {p}" for p in found], rows, ref) if len(found) > 1 else {}


def _by_group(labels: list, groups, rows: dict[str, list[dict]], ref: list[dict] | None) -> dict:
    """{group: {"instances": its instance indices, "rows": {key: CATEGORY_KEYS means and ratios}}}
    for each group of `groups` that some instance's label names, in that order."""
    out = {}
    for group in groups:
        members = [i for i, label in enumerate(labels) if label == group]
        if not members:
            continue
        ref_means = ({key: float(np.mean([ref[i][key] for i in members])) for key in CATEGORY_KEYS}
                     if ref else None)
        table = {}
        for key, records in rows.items():
            means = {name: float(np.mean([records[i][name] for i in members])) for name in CATEGORY_KEYS}
            for name in ("strain", "energy_total"):
                ref_mean = ref_means[name] if ref_means else math.nan
                means[f"{name}_ratio"] = means[name] / ref_mean if ref_means and ref_mean != 0 else math.nan
            table[key] = means
        out[group] = {"instances": members, "rows": table}
    return out

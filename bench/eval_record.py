"""The test instances and the MakeHuman suits of an evaluation record, with their references,
drawn again in this checkout."""

from __future__ import annotations

import json
from pathlib import Path

from physdrape.eval.config import EvalConfig
from physdrape.eval.instances import makehuman_instances, split_instances


def test_instances(path: str, count: int | None = None) -> tuple[list, list[dict], dict]:
    """(instances, reference records, the record) of the evaluation record at `path`: its test
    instances (`physdrape.eval.instances.split_instances` with its settings, the first `count`,
    default all) and per instance its reference as the record holds it (`physdrape.eval.summary.reference`:
    the lowest E_total among the oracle runs that converged). Exits with a message when the record
    has no test references or this checkout draws other garments."""
    record = json.loads(Path(path).read_text())
    test = record["sets"].get("test", {})
    if not test.get("reference"):
        raise SystemExit(f"{path} has no test set with references: run `physdrape eval` with the oracle")
    settings = record["config"]
    described, references = test["instances"], test["reference"]["per_instance"]
    count = len(described) if count is None else min(count, len(described))
    config = EvalConfig(instances=len(described), seed=settings["seed"],
                        poses_per_garment=settings["poses_per_garment"], split_dir=settings["split_dir"],
                        max_garments=settings["max_garments"], dtype=settings["dtype"])
    from physdrape.body.anny_body import get_anny_body

    instances = split_instances(config, get_anny_body())[:count]
    if [inst.garment for inst in instances] != [d["garment"] for d in described[:count]]:
        raise SystemExit(f"the test instances of this checkout are not those of {path}")
    return instances, references[:count], record


def suit_instances(path: str, makehuman_dir: str) -> tuple[list, list[dict], dict, EvalConfig]:
    """(instances, reference records, the record, its EvalConfig) of the MakeHuman set of the
    evaluation record at `path`, the garments read from `makehuman_dir` (`physdrape eval
    --makehuman`'s layout, bodies and wear; the config carries the record's oracle settings).
    Exits with a message when the record has no such set with references or the folder holds
    other garments."""
    record = json.loads(Path(path).read_text())
    if "makehuman" not in record["sets"] or not record["sets"]["makehuman"].get("reference"):
        raise SystemExit(f"{path} has no MakeHuman set with references: run `physdrape eval --makehuman DIR`")
    settings = record["config"]
    config = EvalConfig(makehuman_dir=makehuman_dir, seed=settings["seed"],
                        makehuman_instances=settings["makehuman_instances"],
                        makehuman_max_verts=settings["makehuman_max_verts"],
                        oracle_budget_s=settings["oracle_budget_s"], oracle_tol=settings["oracle_tol"],
                        oracle_max_iters=settings["oracle_max_iters"], dtype=settings["dtype"])
    from physdrape.body.anny_body import get_anny_body

    instances, _ = makehuman_instances(config, get_anny_body())
    suits = record["sets"]["makehuman"]
    if [inst.garment for inst in instances] != [d["garment"] for d in suits["instances"]]:
        raise SystemExit(f"the suits under {makehuman_dir} are not those of {path}")
    return instances, suits["reference"]["per_instance"], record, config

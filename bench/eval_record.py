"""The test instances of an evaluation record and their references, drawn again in this checkout."""

from __future__ import annotations

import json
from pathlib import Path

from physdrape.eval.config import EvalConfig
from physdrape.eval.instances import split_instances


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

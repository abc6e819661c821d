"""The evaluation runner on a tiny protocol: a random-init checkpoint, 2 garments × 2 bodies."""

from __future__ import annotations

import copy
import json
import math
from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh

from physdrape.config_io import to_mapping
from physdrape.eval.evaluate import (
    ABLATION_ROWS,
    Contact,
    MAIN_ROWS,
    EvalConfig,
    InstanceInput,
    _evaluate_set,
    evaluate,
)
from physdrape.eval.instances import Instance
from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet
from physdrape.geometry.proximity import BodySurface
from physdrape.model import DrapeInput, ModelConfig, PhysDrape, Variant
from physdrape.physics import Cloth, Material
from physdrape.checkpoint import load_model, save_checkpoint
from physdrape.eval.report import PUBLISHED_NOTE, render_markdown, write_results
from physdrape.eval.summary import by_pose
from physdrape.train.trainer import TrainConfig



@pytest.fixture(scope="module")
def tiny(tiny_split, tmp_path_factory) -> EvalConfig:
    """The 2 instances of the tiny split (its 2 test garments, one pose each); max_iters (not the
    wall-time budget) stops the oracle: deterministic. The reference cache is the module's own."""
    return EvalConfig(max_garments=2, oracle_budget_s=60.0, oracle_max_iters=2, split_dir=tiny_split,
                      reference_cache=str(tmp_path_factory.mktemp("reference_cache")))


def tiny_checkpoint(root, seed: int = 0):
    torch.manual_seed(seed)
    config = TrainConfig(model=ModelConfig(latent=8, blocks=1))
    return save_checkpoint(root, 1, PhysDrape(config.model), {"train": to_mapping(config)})


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    return tiny_checkpoint(tmp_path_factory.mktemp("ckpt"))


@pytest.fixture(scope="module")
def results(checkpoint, anny_body, tiny):
    return evaluate(checkpoint, tiny, body=anny_body, command="test", log=lambda _: None)


@pytest.fixture(scope="module")
def again(checkpoint, anny_body, tiny, results):
    """The same evaluation run a second time (after `results`: its oracle comes from the cache)."""
    return evaluate(checkpoint, tiny, body=anny_body, command="test", log=lambda _: None)


def all_summaries(res):
    data = res["sets"]["test"]
    yield from ((k, row["summary"]) for k, row in data["rows"].items())
    yield "oracle", data["oracle"]["summary"]
    yield "oracle_refined", data["oracle_refined"]["summary"]
    yield "oracle_settled", data["oracle_settled"]["summary"]
    yield "reference", data["reference"]["summary"]
    yield "x_init", data["x_init"]["summary"]


def test_both_tables_have_all_rows_with_finite_numbers(results, tiny):
    data = results["sets"]["test"]
    assert set(data["rows"]) == {s.key for s in MAIN_ROWS} | {f"ablation:{s.key}" for s in ABLATION_ROWS}
    assert len(data["oracle"]["per_instance"]) == len(data["instances"]) == 2  # the whole (tiny) test split
    assert [i["garment"] for i in data["instances"]] == ["0000_tshirt", "0001_longsleeve"]
    for key, summary in all_summaries(results):
        for name in ("strain", "bend", "b2g_percent", "close_percent", "residual_force", "energy_total", "wall_s",
                     "strain_ratio", "bend_ratio", "energy_total_ratio"):
            assert math.isfinite(summary[name]), (key, name)
    for start in ("x_init", "skinned"):  # context rows: PhysDrape's start and the oracle's
        assert math.isfinite(data[start]["summary"]["strain"]), start
    per_garment = {"strain", "bend", "b2g_percent", "close_percent", "residual_force", "residual_relative",
                   "energy_total", "wall_s", "model_wall_s"}
    assert set(data["rows"]["physdrape_t15"]["per_instance"][0]) == per_garment  # a drape's numbers, no per-vertex field
    md = render_markdown(results)
    assert "## Table 1" in md and "## Table 2" in md and "Skinned (the oracle's start" in md
    for spec in MAIN_ROWS + ABLATION_ROWS:
        assert f"| {spec.label}" in md, spec.label
    assert "| Oracle from the skinned start (" in md and "| X_init" in md
    assert "switched at inference on the full model, not retrained" in md


def test_ratio_to_the_reference_is_the_ratio_of_the_json_numbers(results, tmp_path):
    json_path, md_path = write_results(results, tmp_path)
    loaded = json.loads(json_path.read_text())
    data = loaded["sets"]["test"]
    reference = data["reference"]["summary"]
    for key, row in [*data["rows"].items(), ("x_init", data["x_init"]), ("oracle", data["oracle"])]:
        s = row["summary"]
        for name in ("strain", "bend", "energy_total"):
            assert s[f"{name}_ratio"] == pytest.approx(s[name] / reference[name], rel=1e-12), (key, name)
            assert s[name] == pytest.approx(np.mean([r[name] for r in row["per_instance"]]), rel=1e-12)
    assert md_path.read_text() == render_markdown(results)


def test_reference_is_the_lowest_energy_oracle_result_and_refining_never_raises_the_energy(results, tiny):
    data = results["sets"]["test"]
    model = data["rows"]["physdrape_t15"]["per_instance"]
    oracle, refined = data["oracle"]["per_instance"], data["oracle_refined"]["per_instance"]
    settled = data["oracle_settled"]["per_instance"]
    for m, a, b, c, ref in zip(model, oracle, refined, settled, data["reference"]["per_instance"], strict=True):
        # relax descends from the model's drape, so the polished drape is at most as high as it
        assert b["energy_total"] <= m["energy_total"] + 1e-12
        assert b["wall_s"] == pytest.approx(b["oracle_wall_s"] + m["wall_s"])
        assert c["wall_s"] > c["oracle_wall_s"]  # with the T = 60 drape it starts from
        runs = [("oracle", a), ("oracle_refined", b), ("oracle_settled", c)]
        candidates = [run for run in runs if run[1]["converged"]] or runs
        lowest = min(r["energy_total"] for _, r in candidates)
        assert ref["energy_total"] == lowest
        assert ref["source"] == next(name for name, r in candidates if r["energy_total"] == lowest)
    sources = [r["source"] for r in data["reference"]["per_instance"]]
    assert data["reference"]["summary"]["from_refinement"] == sources.count("oracle_refined")
    assert data["reference"]["summary"]["from_settled"] == sources.count("oracle_settled")
    md = render_markdown(results)
    assert "| Oracle refining PhysDrape (T=15) (" in md and "| Oracle from PhysDrape (T=60) (" in md
    assert "| Reference (lowest E_total of the converged per instance;" in md and "from T=60)" in md
    assert tiny.oracle_settle_steps == 60
    assert "from the model's drape at T = 60 (settled)" in results["oracle_definition"]


def test_the_reference_picks_the_lowest_of_the_oracle_results_earlier_on_ties():
    from physdrape.eval.summary import reference

    a = [{"energy_total": 1.0}, {"energy_total": 2.0}, {"energy_total": 3.0}]
    b = [{"energy_total": 1.0}, {"energy_total": 1.5}, {"energy_total": 2.5}]
    c = [{"energy_total": 0.5}, {"energy_total": 1.5}, {"energy_total": 2.6}]
    assert [r["source"] for r in reference(a, b, c)] == ["oracle_settled", "oracle_refined", "oracle_refined"]
    later = [{"energy_total": 1.0}, {"energy_total": 2.5}, {"energy_total": 2.0}]
    assert [r["source"] for r in reference(a, [], later)] == ["oracle", "oracle", "oracle_settled"]
    assert [r["source"] for r in reference(a, [])] == ["oracle"] * 3
    # a converged result comes before a lower one stopped on its budget; with none converged, the lowest
    converged = [{**r, "converged": True} for r in b]
    a_stopped, c_stopped = ([{**r, "converged": False} for r in runs] for runs in (a, c))
    assert [r["source"] for r in reference(a_stopped, converged, c_stopped)] == ["oracle_refined"] * 3
    assert [r["source"] for r in reference(a_stopped, [], c_stopped)] == ["oracle_settled"] * 3
    with pytest.raises(ValueError, match="oracle_settled has 2 records for 3 instances"):
        reference(a, b, c[:2])


def test_one_instances_reference_takes_any_number_of_named_runs_by_the_same_rule():
    from physdrape.eval.summary import lowest_converged

    runs = [("oracle", {"energy_total": 2.0, "converged": True}), ("cached", {"energy_total": 1.0, "converged": False}),
            ("refined", {"energy_total": 1.5}), ("settled", {"energy_total": 1.5, "converged": True})]
    assert lowest_converged(runs)[0] == "refined"  # the stopped lower one skipped, ties to the earlier
    assert lowest_converged([r for r in runs if r[0] == "cached"])[0] == "cached"  # none converged: the lowest
    with pytest.raises(ValueError, match="no oracle results"):
        lowest_converged([])


def test_without_refinement_the_reference_is_the_oracle(checkpoint, anny_body, tiny, results):
    res = evaluate(checkpoint, replace(tiny, instances=1, oracle_refine=False, oracle_settle_steps=0,
                                       reference_cache=None), body=anny_body, command="test", log=lambda _: None)
    data = res["sets"]["test"]
    # no cache: the oracle ran again, to the numbers of the first run (max_iters stops it)
    assert res["reference_cache"] is None and not data["oracle"]["per_instance"][0]["cached"]
    skip = ("cached", "wall_s", "history")
    assert ({k: v for k, v in data["oracle"]["per_instance"][0].items() if k not in skip}
            == {k: v for k, v in results["sets"]["test"]["oracle"]["per_instance"][0].items() if k not in skip})
    assert data["oracle_refined"] is None and data["oracle_settled"] is None
    assert data["reference"]["summary"]["strain"] == data["oracle"]["summary"]["strain"]
    assert data["oracle"]["summary"]["strain_ratio"] == pytest.approx(1.0)


def test_paper_rows_are_labelled_as_context(results):
    md = render_markdown(results)
    context = md[md.index("## Context"):]
    assert PUBLISHED_NOTE in context and "different data" in PUBLISHED_NOTE
    for method in ("DeePSD", "DIG", "DrapeNet"):
        assert method in context and method not in md[: md.index("## Context")]
    assert "| DeePSD | 7.22 | 0.01 | 7.2 |" in context
    assert results["published"]["note"] == PUBLISHED_NOTE


def test_tables_are_reproducible_for_a_seed(results, again):
    assert render_markdown(again, timing=False) == render_markdown(results, timing=False)
    for key, row in results["sets"]["test"]["rows"].items():
        for a, b in zip(row["per_instance"], again["sets"]["test"]["rows"][key]["per_instance"]):
            timing = ("wall_s", "model_wall_s")
            assert {k: v for k, v in a.items() if k not in timing} == {k: v for k, v in b.items() if k not in timing}


def test_a_rerun_reads_the_oracle_from_the_reference_cache_with_identical_numbers(results, again, tiny):
    first = results["sets"]["test"]["oracle"]["per_instance"]
    assert not any(r["cached"] for r in first) and results["reference_cache"]["misses"] == 2
    assert again["reference_cache"] == {"dir": tiny.reference_cache, "hits": 2, "misses": 0}
    cached = again["sets"]["test"]["oracle"]["per_instance"]
    assert all(r["cached"] for r in cached)
    for a, b in zip(first, cached, strict=True):
        assert {k: v for k, v in a.items() if k != "cached"} == {k: v for k, v in b.items() if k != "cached"}
    assert again["sets"]["test"]["oracle"]["summary"]["cached"] == 2
    assert "were read from the reference cache" in render_markdown(again)


def test_per_category_means_and_ratios_are_those_of_the_categorys_instances(results, tmp_path):
    json_path, _ = write_results(results, tmp_path)
    data = json.loads(json_path.read_text())["sets"]["test"]
    categories = data["categories"]
    assert list(categories) == ["tshirt", "longsleeve"]  # the tiny split's two test garments, in table order
    reference = data["reference"]["per_instance"]
    for category, entry in categories.items():
        members = entry["instances"]
        assert [data["instances"][i]["category"] for i in members] == [category] * len(members)
        ref = {name: np.mean([reference[i][name] for i in members]) for name in ("strain", "energy_total")}
        for key in [*data["rows"], "x_init", "skinned", "oracle", "oracle_refined", "oracle_settled", "reference"]:
            per_instance = (data[key] if key in data else data["rows"][key])["per_instance"]
            row = entry["rows"][key]
            for name in ("strain", "energy_total", "b2g_percent"):
                assert row[name] == pytest.approx(np.mean([per_instance[i][name] for i in members]), rel=1e-12)
            for name in ("strain", "energy_total"):
                assert row[f"{name}_ratio"] == pytest.approx(row[name] / ref[name], rel=1e-12), (category, key)
        assert entry["rows"]["reference"]["energy_total_ratio"] == pytest.approx(1.0)
    md = render_markdown(results)
    table = md[md.index("E_total / reference by garment category"):md.index("## Table 2")]
    assert "| Method | all (2) | tshirt (1) | longsleeve (1) |" in table
    label = results["row_definitions"]["physdrape_t15"]["label"]
    (line,) = [row for row in table.splitlines() if row.startswith(f"| {label} |")]
    assert len(line.split(" | ")) == 4 and "–" not in line  # all, tshirt, longsleeve: every ratio finite
    assert data["poses"] == {} and "by pose" not in md  # one pose per garment: no pose table


def test_with_two_poses_the_report_has_a_table_by_pose(results):
    data = copy.deepcopy(results["sets"]["test"])
    rows = {key: (data[key] if key in data else data["rows"][key])["per_instance"]
            for key in [*data["rows"], "x_init", "skinned", "oracle", "oracle_refined", "oracle_settled", "reference"]}
    data["poses"] = by_pose([0, 1], rows, data["reference"]["per_instance"])  # as if the two were poses 0 and 1
    assert [entry["instances"] for entry in data["poses"].values()] == [[0], [1]]
    for (pose, entry), i in zip(data["poses"].items(), (0, 1)):
        row = entry["rows"]["physdrape_t15"]
        assert row["energy_total_ratio"] == pytest.approx(
            rows["physdrape_t15"][i]["energy_total"] / rows["reference"][i]["energy_total"], rel=1e-12), pose
    md = render_markdown({**results, "sets": {**results["sets"], "test": data}})
    table = md[md.index("E_total / reference by pose"):md.index("## Table 2")]
    assert "| Method | all (2) | pose 0 (1) | pose 1 (1) |" in table
    assert by_pose([0, 0], rows, None) == {}


def sheet_over_box_edge() -> DrapeInput:
    """A 40 cm sheet lying on a 1 m box, half of it overhanging an edge (the oracle converges in ~1 s)."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    bodies = BodySurface(torch.tensor(np.asarray(box.vertices)), torch.tensor(np.asarray(box.faces)))
    verts, faces = grid_sheet(9, 9, width=0.4, height=0.4)
    batch = GarmentBatch.pack([Garment.from_mesh(verts + np.array([0.25, 0.503, -0.2]), faces, name="sheet")])
    return DrapeInput(batch, Cloth.build(batch, Material()), batch.rest.clone(), bodies, torch.zeros_like(batch.vert_garment))


def test_converged_oracle_row_meets_its_tolerance(checkpoint):
    model, _ = load_model(checkpoint, variant=Variant.FULL)
    config = EvalConfig(instances=1, oracle_budget_s=30.0)
    inst = Instance("test", 0, "sheet", 0, 0, 81, lambda: InstanceInput(sheet_over_box_edge(), 0.0, None))
    data = _evaluate_set([inst], {"full": model}, {"full": ("full", 3, True)}, config, Contact.of(model),
                         log=lambda _: None)
    (record,) = data["oracle"]["per_instance"]
    assert record["converged"], record["reason"]
    assert record["oracle_residual"] < config.oracle_tol
    assert data["oracle"]["summary"]["converged"] == 1
    # the energy the oracle reports is the one the rows are measured with
    assert record["energy_total"] == pytest.approx(record["oracle_energy_total"], rel=1e-9)
    assert record["history"][-1]["residual"] < config.oracle_tol


def test_tiny_protocol_oracle_rows_meet_the_tolerance_when_converged(results, tiny):
    for record in results["sets"]["test"]["oracle"]["per_instance"]:
        assert record["converged"] == (record["reason"] == "converged" or record["reason"] == "line_search")
        if record["converged"]:
            assert record["oracle_residual"] < tiny.oracle_tol


def test_what_the_network_adds_is_the_model_row_minus_the_solver_alone(results):
    data = results["sets"]["test"]
    md = render_markdown(results)
    table = md[md.index("What the network adds"):].split("\n\n")[1].splitlines()
    assert [line.split(" | ")[0] for line in table[2:]] == ["| 3", "| 15"]
    for line, (model, alone) in zip(table[2:], (("physdrape_t3", "physics_only_t3"), ("physdrape_t15", "physics_only")),
                                    strict=True):
        cells = [c.strip() for c in line.strip("|").split("|")]
        a, b = data["rows"][model]["summary"], data["rows"][alone]["summary"]
        assert float(cells[3]) == pytest.approx(a["energy_total_ratio"] - b["energy_total_ratio"], abs=6e-4)
        assert float(cells[6]) == pytest.approx(a["strain_ratio"] - b["strain_ratio"], abs=6e-4)

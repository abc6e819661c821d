"""Manifests of drape jobs: reading and checking lines, shards, batches, and `run_manifest`'s
outputs, resume, failures and summaries on the tiny test model."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from physdrape import checkpoint
from physdrape.api import DrapeError, ManifestError, Motion, Outputs, ranks_from_env, read_manifest, run_manifest
from physdrape.api.manifest_run import batches, summary_path
from physdrape.physics.presets import MATERIAL_PRESETS


def _write(path: Path, lines: list) -> Path:
    path.write_text("".join((line if isinstance(line, str) else json.dumps(line)) + "\n" for line in lines))
    return path


def _summary(out: Path, rank: int = 0, world_size: int = 1) -> dict:
    return json.loads(summary_path(out, rank, world_size).read_text())


@pytest.fixture(scope="module")
def far_obj(tmp_path_factory) -> Path:
    """The default T-shirt 2 m beside the body: it hangs on nothing, so draping it fails."""
    from physdrape.garments import default_garment
    from physdrape.geometry.mesh import write_mesh

    g = default_garment()
    path = tmp_path_factory.mktemp("far") / "far.obj"
    write_mesh(path, g.verts + np.array([2.0, 0.0, 0.0]), g.faces)
    return path


def test_lines_become_jobs_with_defaults_and_resolved_paths(tmp_path, far_obj):
    (tmp_path / "g").mkdir()
    (tmp_path / "g" / "tee.obj").write_text(far_obj.read_text())
    path = _write(tmp_path / "jobs.jsonl", [
        {"id": "a", "garment": "tshirt:7", "shape": {"weight": 0.8}, "pose": "stand", "material": "denim"},
        "",
        {"garment": "g/tee.obj", "units": "cm", "material": {"preset": "silk", "k_bend": 1e-6}, "id": 12},
        {"pose": {"bvh": "g/tee.obj", "frame": 2}, "shape": [0.5] * 6},
    ])
    (tmp_path / "g" / "w.bvh").write_text("")
    manifest = read_manifest(path)
    assert [b.line for b in manifest.bad] == [4] and "must be a .bvh file" in manifest.bad[0].error
    a, tee = manifest.jobs
    assert (a.index, a.line, a.id, a.garment, a.shape, a.pose) == (0, 1, "a", "tshirt:7", {"weight": 0.8}, "stand")
    assert a.material == MATERIAL_PRESETS["denim"] and a.units == "m" and a.rig == "anny"
    assert (tee.index, tee.line, tee.id, tee.units) == (1, 3, "12", "cm")
    assert tee.garment == str(tmp_path / "g" / "tee.obj")
    assert tee.material.k_bend == 1e-6 and tee.material.mu == MATERIAL_PRESETS["silk"].mu
    assert manifest.bad[0].index == 2
    path = _write(tmp_path / "more.jsonl", [{"pose": {"bvh": "g/w.bvh", "frame": 2}}, {"pose": [[0, 0.1, 0]] * 3,
                                                                                          "material": {"mu": 1e6}}])
    bvh, array = read_manifest(path).jobs
    assert bvh.id == "line-000001" and bvh.garment == "default" and bvh.shape is None and bvh.rig == "cmu_mb"
    assert bvh.pose == Motion(tmp_path / "g" / "w.bvh", 2, warm_start=False)
    assert array.pose.shape == (3, 3) and array.notes and "trained range" in array.notes[0]


def test_every_bad_line_is_named_with_all_its_faults(tmp_path):
    path = _write(tmp_path / "bad.jsonl", [
        {"id": "a"},
        "not json",
        {"id": "a"},
        {"garmnet": "default"},
        {"garment": "hoodie:3", "shape": {"weight": 1.8}, "pose": "jump", "material": "wool"},
        {"garment": "missing.obj", "material": {"preset": "silk", "mu": -3}},
        {"id": "../up", "pose": {"bvh": "x.bvh", "frame": -1}, "units": "inch"},
        [1, 2],
        {"id": "summary.rank0-of-1.json"},
    ])
    manifest = read_manifest(path)
    assert [j.id for j in manifest.jobs] == ["a"]
    errors = {b.line: b.error for b in manifest.bad}
    assert sorted(errors) == [2, 3, 4, 5, 6, 7, 8, 9]
    assert "not JSON" in errors[2] and "repeats line 1" in errors[3] and "'garmnet'" in errors[4]
    for fault in ("hoodie:3", "weight = 1.8", "'jump'", "'wool'"):
        assert fault in errors[5]
    assert "no such file" in errors[6] and "mu must be positive" in errors[6]
    assert "folder name" in errors[7] and "frame" in errors[7] and "'inch'" in errors[7]
    assert "JSON object" in errors[8] and "folder name" in errors[9]
    with pytest.raises(ManifestError, match=r"8 bad line\(s\), nothing draped: line 2: not JSON") as info:
        run_manifest(None, manifest, tmp_path / "out")
    assert len(info.value.bad) == 8 and not (tmp_path / "out").exists()
    with pytest.raises(DrapeError, match="no such file"):
        read_manifest(tmp_path / "nothing.jsonl")


def test_smpl_manifests_take_files_betas_and_theta(tmp_path, far_obj):
    path = _write(tmp_path / "smpl.jsonl", [
        {"garment": str(far_obj), "shape": [1.0, -0.5], "pose": [[0.0, 0.0, 0.0]] * 24},
        {"garment": "default", "shape": {"weight": 0.3}, "pose": "stand"},
    ])
    manifest = read_manifest(path, smpl=True)
    assert [j.shape for j in manifest.jobs] == [[1.0, -0.5]]
    [bad] = manifest.bad
    assert "made for the Anny body" in bad.error and "β" in bad.error and "'stand'" in bad.error


def test_shards_split_jobs_by_index_and_batches_share_a_shape(tmp_path):
    lines = [{"id": f"j{k}", "shape": {"weight": 0.2 + 0.6 * (k % 2)}} for k in range(7)]
    lines.insert(3, "oops")
    manifest = read_manifest(_write(tmp_path / "jobs.jsonl", lines))
    shards = [manifest.shard(rank, 3) for rank in range(3)]
    assert sorted(j.id for s in shards for j in s.jobs) == sorted(j.id for j in manifest.jobs)
    assert all(j.index % 3 == rank for rank, s in enumerate(shards) for j in s.jobs)
    assert [b.line for b in shards[0].bad] == [4]  # the bad line keeps its place (index 3)
    groups = list(batches(manifest.jobs, 2))
    assert [[j.id for j in g] for g in groups] == [["j0", "j2"], ["j1", "j3"], ["j4", "j6"], ["j5"]]
    assert all(len({json.dumps(j.shape) for j in g}) == 1 for g in groups)
    with pytest.raises(DrapeError, match="0 <= rank < world size"):
        manifest.shard(3, 3)


def test_ranks_come_from_torchrun_variables():
    assert ranks_from_env({}) == (0, 1)
    assert ranks_from_env({"RANK": "3", "WORLD_SIZE": "4", "LOCAL_RANK": "1"}) == (3, 4)
    for env in ({"RANK": "4", "WORLD_SIZE": "4"}, {"RANK": "0"}, {"RANK": "x", "WORLD_SIZE": "2"}):
        with pytest.raises(DrapeError, match="RANK|rank"):
            ranks_from_env(env)


def test_run_writes_each_job_atomically_and_resumes(draper, tmp_path, monkeypatch):
    path = _write(tmp_path / "jobs.jsonl", [
        {"id": "a", "pose": "stand", "material": "denim"},
        {"id": "b", "pose": "t-pose", "shape": {"weight": 0.8}},
        {"id": "c", "pose": "relaxed", "material": "silk"},
        {"id": "d", "pose": "a-pose"},
    ])
    out = tmp_path / "out"
    calls, stop_at = [], [2]
    drape = draper.drape

    def interrupted_second_call(*args, **kwargs):
        calls.append(len(args[0]))
        if len(calls) in stop_at:
            stop_at.clear()
            raise KeyboardInterrupt
        return drape(*args, **kwargs)

    monkeypatch.setattr(draper, "drape", interrupted_second_call)
    with pytest.raises(KeyboardInterrupt):
        run_manifest(draper, path, out, batch_size=2)
    assert calls == [2, 1] and sorted(p.name for p in out.iterdir()) == ["a", "c", "summary.rank0-of-1.json"]
    summary = _summary(out)
    assert summary["status"] == "interrupted" and summary["done"] == ["a", "c"]
    report = json.loads((out / "a" / "report.json").read_text())
    assert sorted(p.name for p in (out / "a").iterdir()) == ["garment.ply", "report.json"]
    assert report["job"] == {"id": "a", "pose": "stand", "material": "denim"} and report["steps"] == draper.steps
    [entry] = report["results"]
    assert entry["pose"] == "stand" and entry["material"]["mu_Pa"] == MATERIAL_PRESETS["denim"].mu
    assert np.isfinite(entry["E_strain_J"]) and report["outputs"] == list(Outputs.LEAN.files)

    calls.clear()
    (out / ".d.leftover1").mkdir()  # what a killed run leaves: a hidden temporary folder
    summary = run_manifest(draper, path, out, batch_size=2)
    assert calls == [1, 1]  # b and d have different shapes: one call each
    assert (summary.done, summary.skipped, summary.status) == (["b", "d"], ["a", "c"], "complete")
    assert not [p for p in out.iterdir() if p.name.startswith(".")]
    calls.clear()
    assert run_manifest(draper, path, out).skipped == ["a", "b", "c", "d"] and calls == []


def test_changed_jobs_are_refused_unless_forced_and_richer_outputs_redrape(draper, tmp_path):
    path = _write(tmp_path / "jobs.jsonl", [{"id": "a"}, {"id": "b", "pose": "stand"}])
    out = tmp_path / "out"
    run_manifest(draper, path, out)
    before = (out / "b" / "garment.ply").read_bytes()
    _write(path, [{"id": "a"}, {"id": "b", "pose": "t-pose"}])
    with pytest.raises(DrapeError, match=r"1 job folder\(s\) hold another drape.*b \(line 2\): it holds another job"):
        run_manifest(draper, path, out)
    assert (out / "b" / "garment.ply").read_bytes() == before
    summary = run_manifest(draper, path, out, force=True, outputs="meshes")
    assert summary.done == ["a", "b"]  # a: more files asked for; b: replaced
    assert {"body.obj", "drape.glb", "garment.obj"} <= {p.name for p in (out / "a").iterdir()}
    assert json.loads((out / "b" / "report.json").read_text())["results"][0]["pose"] == "t-pose"
    (out / "x").mkdir()
    _write(path, [{"id": "x"}])
    with pytest.raises(DrapeError, match="no readable report.json"):
        run_manifest(draper, path, out)


def test_a_folder_draped_with_other_passes_is_stale_and_an_older_report_means_one(draper, tmp_path):
    """The network's passes change the drape: a folder made with one pass does not count for a run
    with two; a report written before the record named the passes counts as one pass."""
    from physdrape.api.manifest_run import job_record, stale_reason

    path = _write(tmp_path / "jobs.jsonl", [{"id": "a"}])
    out = tmp_path / "out"
    run_manifest(draper, path, out)
    [job] = read_manifest(path).jobs
    record = job_record(draper, job, refine=False)
    assert record["passes"] == draper.model_config.passes == 1 and stale_reason(out / "a", record) is None
    assert stale_reason(out / "a", {**record, "passes": 2}) == "its passes is 1, not 2"
    report = json.loads((out / "a" / "report.json").read_text())
    del report["passes"]
    (out / "a" / "report.json").write_text(json.dumps(report))
    assert stale_reason(out / "a", record) is None


def test_a_failing_job_fails_alone_and_is_listed(draper, tmp_path, far_obj):
    path = _write(tmp_path / "jobs.jsonl", [{"id": "ok"}, {"id": "far", "garment": str(far_obj)},
                                            "{bad", {"id": "ok2", "pose": "stand"}])
    out = tmp_path / "out"
    summary = run_manifest(draper, path, out, batch_size=3, skip_bad_lines=True)
    assert summary.done == ["ok", "ok2"] and [f["id"] for f in summary.failed] == ["far"]
    assert "neither touches nor surrounds" in summary.failed[0]["error"] and summary.failed[0]["line"] == 2
    assert summary.bad_lines == [{"line": 3, "error": summary.bad_lines[0]["error"]}]
    assert _summary(out)["failed"] == summary.failed and not (out / "far").exists()


DOC = Path(__file__).resolve().parents[2] / "docs" / "manifest.md"


def test_the_documented_manifest_and_python_example_work(tiny_checkpoint, anny_body, tmp_path, monkeypatch):
    text = DOC.read_text()
    lines = re.search(r"```json\n(.*?)```", text, re.DOTALL).group(1).splitlines()
    (tmp_path / "garments").mkdir()
    (tmp_path / "garments" / "shirt.obj").write_text("")  # only its existence is checked before draping
    (tmp_path / "walk.bvh").write_text("")
    manifest = read_manifest(_write(tmp_path / "example.jsonl", lines))
    assert not manifest.bad and len(manifest.jobs) == len(lines) == 5
    assert [j.id for j in manifest.jobs][2] == "line-000003"

    code = re.search(r"## From Python\n\n```python\n(.*?)```", text, re.DOTALL).group(1)
    _write(tmp_path / "jobs.jsonl", [{"id": "a", "pose": "stand"}, {"pose": "t-pose"}])
    monkeypatch.setattr(checkpoint, "bundled_model", lambda: Path(tiny_checkpoint))
    monkeypatch.chdir(tmp_path)
    exec(compile(code.replace("steps=15", "steps=2"), "manifest.md", "exec"), {})  # noqa: S102 - our own docs
    assert sorted(p.name for p in (tmp_path / "DIR").iterdir()) == ["a", "line-000002", "summary.rank0-of-1.json"]

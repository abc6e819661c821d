"""`physdrape drape` and `physdrape fit` smoke runs on a tiny test model, and every bad-input path."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from physdrape import api, checkpoint
from physdrape.cli import build_parser, main

BVH_DIR = Path(__file__).resolve().parents[2].parent / "shared" / "data" / "cmu_bvh"
BVH_FILES = sorted(BVH_DIR.glob("*.bvh")) if BVH_DIR.is_dir() else []
FAST = ["--steps", "2", "--render-size", "48"]


@pytest.fixture
def bundled(tiny_checkpoint, anny_body, monkeypatch):
    """Make the tiny model the 'bundled' one, so `physdrape drape` runs with no arguments at all."""
    monkeypatch.setattr(checkpoint, "bundled_model", lambda: Path(tiny_checkpoint))
    return tiny_checkpoint


@pytest.fixture(scope="module")
def default_obj(tmp_path_factory) -> Path:
    from physdrape.garments import default_garment
    from physdrape.geometry.mesh import write_mesh

    g = default_garment()
    path = tmp_path_factory.mktemp("garments") / "tee.obj"
    write_mesh(path, g.verts, g.faces)
    return path


def _report(out: Path) -> dict:
    return json.loads((out / "report.json").read_text())


def test_drape_without_arguments(bundled, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(["drape"]) == 0
    out = tmp_path / "physdrape_out"
    names = {p.name for p in out.iterdir()}
    assert {"garment.obj", "garment.ply", "body.obj", "body.ply", "drape.glb", "render.png", "report.json"} <= names
    report = _report(out)
    [entry] = report["results"]
    for key in ("E_strain_J", "E_bend_J", "B2G_percent", "residual_force_N"):
        assert np.isfinite(entry[key])
    assert report["wall_time_s"] > 0 and report["steps"] == 15 and entry["pose"] == api.DEFAULT_POSE
    assert entry["material"]["mu_Pa"] == pytest.approx(2.36e4)  # cotton = SNUG's default
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]  # no temp dir left behind
    assert "wrote 1 drape" in capsys.readouterr().out


def test_drape_with_flags_and_force(bundled, tmp_path, default_obj):
    out = tmp_path / "o"
    args = ["drape", "--garment", str(default_obj), "--shape", "gender=0.2,weight=0.8", "--pose", "stand",
            "--material", "denim", "--k-bend", "1e-4", "--out", str(out), *FAST]
    assert main(args) == 0
    [entry] = _report(out)["results"]
    assert entry["pose"] == "stand" and entry["garment"] == "tee"
    assert entry["material"]["density_kg_m2"] == pytest.approx(0.40) and entry["material"]["k_bend_J"] == 1e-4
    assert _report(out)["shape"] == {"gender": 0.2, "weight": 0.8}
    before = (out / "garment.obj").read_bytes()
    assert main(args[:-4] + ["--pose", "t-pose"] + FAST) == 2  # existing outputs are kept
    assert (out / "garment.obj").read_bytes() == before
    assert main(args[:-4] + ["--pose", "t-pose", "--force"] + FAST) == 0
    assert _report(out)["results"][0]["pose"] == "t-pose"


def test_many_garments_one_batch(bundled, tmp_path, default_obj):
    out = tmp_path / "many"
    assert main(["drape", "--garment", "default", "--garment", str(default_obj), "--out", str(out), *FAST]) == 0
    report = _report(out)
    assert report["num_results"] == 2
    for entry in report["results"]:
        assert (out / entry["directory"] / "garment.glb").exists() is False
        assert (out / entry["directory"] / "drape.glb").is_file()
    assert report["results"][0]["timings_s"]["batch_size"] == 2


@pytest.mark.skipif(not BVH_FILES, reason=f"no CMU BVH files in {BVH_DIR}")
def test_bvh_frames_warm_started_or_batched(bundled, tmp_path):
    out = tmp_path / "bvh"
    assert main(["drape", "--bvh", str(BVH_FILES[0]), "--frames", "0:2", "--out", str(out), *FAST]) == 0
    results = _report(out)["results"]
    assert [e["pose"] for e in results] == [f"{BVH_FILES[0].name}#0", f"{BVH_FILES[0].name}#1"]
    assert [e["init"] for e in results] == ["skinning", "warm"]  # warm start is the default
    cold = tmp_path / "cold"
    assert main(["drape", "--bvh", str(BVH_FILES[0]), "--frames", "0:2", "--no-warm-start", "--out", str(cold),
                 *FAST]) == 0
    results = _report(cold)["results"]
    assert [e["init"] for e in results] == ["skinning", "skinning"] and results[0]["timings_s"]["batch_size"] == 2


@pytest.mark.skipif(not BVH_FILES, reason=f"no CMU BVH files in {BVH_DIR}")
def test_bvh_frames_have_their_arms_turned_out_unless_kept(bundled, tmp_path):
    path = BVH_DIR / "131_01.bvh"  # its frame 100 hangs the arms against the torso
    if not path.is_file():
        pytest.skip(f"no {path}")
    out = tmp_path / "turned"
    assert main(["drape", "--bvh", str(path), "--frame", "100", "--out", str(out), *FAST]) == 0
    [entry] = _report(out)["results"]
    assert len(entry["arms_turned_out_deg"]) == 2 and max(entry["arms_turned_out_deg"]) > 0
    kept = tmp_path / "kept"
    assert main(["drape", "--bvh", str(path), "--frame", "100", "--keep-arms", "--out", str(kept), *FAST]) == 0
    assert "arms_turned_out_deg" not in _report(kept)["results"][0]


def test_fit_places_and_writes(anny_body, tmp_path, default_obj):
    from physdrape.garments import default_garment
    from physdrape.geometry.mesh import read_mesh, write_mesh

    g = default_garment()
    moved = tmp_path / "other_body.obj"
    write_mesh(moved, g.verts + np.array([0.02, 0.12, -0.01]), g.faces)  # authored for another body
    out = tmp_path / "fitted.obj"
    assert main(["fit", str(moved), "--out", str(out), "--iters", "1"]) == 0
    verts, faces = read_mesh(out)
    assert len(faces) == len(g.faces)
    assert np.abs(verts - g.verts).mean() < 0.01  # back where it belongs (within a centimetre)
    assert main(["fit", str(moved), "--out", str(out), "--iters", "0"]) == 2  # no overwrite without --force


def _write_bad(tmp_path: Path, kind: str, default_obj: Path) -> str:
    from physdrape.geometry.mesh import read_mesh, write_mesh

    verts, faces = read_mesh(default_obj)
    path = tmp_path / f"{kind}.obj"
    if kind == "centimetres":
        write_mesh(path, verts * 100.0, faces)
    elif kind == "nonmanifold":  # a third face on an existing edge
        a, b = faces[0, 0], faces[0, 1]
        verts = np.vstack([verts, verts[a] + [0.0, 0.0, 0.01]])
        write_mesh(path, verts, np.vstack([faces, [[a, b, len(verts) - 1]]]))
    elif kind == "garbage":
        path.write_text("this is not a mesh\n")
    return str(path)


BAD = [
    (["--material", "velvet"], "silk, cotton, denim, leather"),
    (["--pose", "dance"], "choose one of rest, a-pose"),
    (["--shape", "weight=1.5"], r"outside \[0, 1\]"),
    (["--shape", "wieght=0.5"], "expected names in"),
    (["--shape", "weight"], "NAME=VALUE"),
    (["--garment", "no/such.obj"], "no such file"),
    (["--garment", "@centimetres"], "metres"),
    (["--garment", "@nonmanifold"], "more than two faces"),
    (["--garment", "@garbage"], "garbage.obj"),
    (["--category", "hoodie"], "tshirt, longsleeve"),
    (["--mu", "-5"], "must be positive"),
    (["--frames", "0:4"], "give --bvh FILE"),
    (["--bvh", "no/such.bvh"], "BVH file not found"),
    (["--steps", "-1"], "steps must be a non-negative integer"),
    (["--passes", "0"], "passes must be an integer ≥ 1"),
    (["--checkpoint", "no/such/dir"], "no/such/dir does not exist"),
    (["--out", "@file/sub"], "not writable"),
    (["--out", "@file"], "not a directory"),
]


@pytest.mark.parametrize(("flags", "pattern"), BAD, ids=[" ".join(f) for f, _ in BAD])
def test_bad_input_exits_2_without_outputs(bundled, tmp_path, default_obj, capsys, flags, pattern):
    import re

    (tmp_path / "file").write_text("x")
    flags = [(_write_bad(tmp_path, f[1:], default_obj) if f.startswith("@") and f[1:] in
              ("centimetres", "nonmanifold", "garbage") else str(tmp_path / f[1:]) if f.startswith("@") else f)
             for f in flags]
    out = tmp_path / "out"
    args = ["drape", *FAST, *flags] + ([] if "--out" in flags else ["--out", str(out)])
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.startswith("physdrape: error:") and "Traceback" not in err
    assert re.search(pattern, err), err
    assert not out.exists()


def test_missing_bundled_model_says_how_to_get_one(tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(checkpoint, "bundled_model", lambda: tmp_path / "none")
    assert main(["drape", "--out", str(tmp_path / "o")]) == 2
    assert "physdrape train" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_fit_bad_inputs(tmp_path, default_obj, capsys):
    cm = _write_bad(tmp_path, "centimetres", default_obj)
    assert main(["fit", cm, "--out", str(tmp_path / "f.obj"), "--iters", "0"]) == 2
    assert "metres" in capsys.readouterr().err
    assert main(["fit", str(default_obj), "--out", str(tmp_path / "f.stl")]) == 2
    assert ".obj or .ply" in capsys.readouterr().err
    assert not (tmp_path / "f.obj").exists()


def test_train_subcommand_still_parses():
    args = build_parser().parse_args(["train", "--config", "c.yaml", "--run-dir", "r", "--steps", "3"])
    assert args.command == "train" and args.steps == 3 and args.func.__name__ == "cmd_train"


def test_train_init_from_overrides_the_configs_and_a_recipe_refuses_it(tmp_path, monkeypatch, capsys):
    from physdrape.train import data, trainer

    seen = {}

    class Recorder:
        def __init__(self, config, source, run_dir, device=None, compile_network=False):
            seen.update(config=config, run_dir=run_dir)

        def run(self, resume=False):
            return []

    monkeypatch.setattr(trainer, "Trainer", Recorder)
    monkeypatch.setattr(data, "DrapeSource", lambda *args, **kwargs: None)
    root = Path(__file__).resolve().parents[2]
    config = str(root / "configs/global/full_energy.yaml")
    assert main(["train", "--config", config, "--run-dir", str(tmp_path / "r"), "--init-from", "elsewhere"]) == 0
    assert seen["config"].optim.init_from == "elsewhere"
    assert main(["train", "--config", config, "--run-dir", str(tmp_path / "r")]) == 0
    assert seen["config"].optim.init_from == "runs/gnn_energy"  # the config's own
    recipe = ["train", "--recipe", str(root / "configs/recipes/shipped.yaml"), "--run-dir", str(tmp_path / "s")]
    assert main([*recipe, "--init-from", "elsewhere"]) == 2
    assert "--init-from" in capsys.readouterr().err


def test_train_instances_only_builds_the_cache_and_stops(tmp_path, monkeypatch, capsys):
    from physdrape.train import data, trainer

    built = []
    monkeypatch.setattr(data, "DrapeSource", lambda config, model: built.append(config.instances))
    monkeypatch.setattr(trainer, "Trainer", lambda *args, **kwargs: pytest.fail("--instances-only trains nothing"))
    root = Path(__file__).resolve().parents[2]
    assert main(["train", "--config", str(root / "configs/global/gnn_energy.yaml"), "--run-dir", str(tmp_path / "r"),
                 "--instances-only"]) == 0
    assert built == ["runs/instances"] and "instance cache ready" in capsys.readouterr().out
    assert not (tmp_path / "r").exists()
    uncached = tmp_path / "uncached.yaml"
    uncached.write_text((root / "configs/global/gnn_energy.yaml").read_text().replace("instances: runs/instances",
                                                                                       'instances: ""'))
    assert main(["train", "--config", str(uncached), "--run-dir", str(tmp_path / "r"), "--instances-only"]) == 2
    assert "data.instances" in capsys.readouterr().err

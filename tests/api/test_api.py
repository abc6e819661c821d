"""The Python API on a tiny test model: shapes, batching, materials, errors, saving, pictures."""

from __future__ import annotations

import re
import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch
from device_params import needs_compiler

from physdrape import api, checkpoint
from physdrape.api import DrapeError, Draper
from physdrape.physics.material import Material
from physdrape.physics.presets import MATERIAL_PRESETS, TRAINED_RANGES, material_preset


def test_drape_returns_documented_shapes_and_dtypes(draper, anny_body):
    [res] = draper.drape("default")
    v = len(res.faces) and res.verts.shape[0]
    assert res.verts.shape == (v, 3) and res.verts.dtype == np.float32
    assert res.x_init.shape == (v, 3) and res.faces.dtype == np.int64 and res.faces.shape[1] == 3
    assert res.body_verts.shape == (anny_body.num_verts, 3) and res.body_faces.shape == (anny_body.num_faces, 3)
    assert res.vertex_residual.shape == (v,) and res.inside_faces.shape == (len(res.faces),)
    assert set(res.metrics) == {"strain", "bend", "b2g_percent", "close_percent", "residual_force", "residual_relative",
                                "piece_crossings"} and res.metrics["piece_crossings"] == 0
    assert all(np.isfinite(x) for x in res.metrics.values())
    assert {"body_s", "init_s", "model_s", "total_s", "per_garment_s"} <= set(res.timings)
    assert np.isfinite(res.verts).all() and not np.allclose(res.verts, res.x_init)
    assert res.pose == api.DEFAULT_POSE and res.material == Material()
    mesh = res.to_trimesh()
    assert mesh.vertices.shape == res.verts.shape and len(mesh.faces) == len(res.faces)


def test_batch_equals_singles(draper):
    batch = draper.drape(["default", "default"], material=["silk", "denim"], pose=["stand", "t-pose"])
    singles = [draper.drape("default", material="silk", pose="stand")[0],
               draper.drape("default", material="denim", pose="t-pose")[0]]
    for b, s in zip(batch, singles):
        np.testing.assert_allclose(b.verts, s.verts, atol=2e-5)
        np.testing.assert_allclose(b.body_verts, s.body_verts, atol=1e-6)
        assert b.metrics["strain"] == pytest.approx(s.metrics["strain"], rel=1e-3, abs=1e-7)


def test_heavier_softer_material_sags_more(draper):
    heavy_soft = Material(mu=1.59e4, lam=2.0e4, k_bend=1e-6, density=0.7)
    light_stiff = Material(mu=6.36e4, lam=9.0e4, k_bend=1e-5, density=0.043)
    heavy, light, silk, leather = draper.drape("default", material=[heavy_soft, light_stiff, "silk", "leather"],
                                                steps=15)
    assert heavy.verts[:, 1].mean() < light.verts[:, 1].mean() - 1e-5
    assert np.abs(silk.verts - leather.verts).max() > 1e-4  # the preset reaches the physics


def test_presets_inside_trained_ranges():
    assert material_preset("cotton") == Material()  # SNUG's default
    for name, m in MATERIAL_PRESETS.items():
        for field, (lo, hi) in TRAINED_RANGES.items():
            assert lo <= getattr(m, field) <= hi, (name, field)
    densities = [m.density for m in MATERIAL_PRESETS.values()]
    assert densities == sorted(densities)  # silk → leather, lightest first


def test_skinning_transfer_is_cached(draper):
    draper.drape("default")
    template = draper.garment("default")
    first = draper.transfer(template, "anny")
    draper.drape("default", pose="stand")
    assert draper.transfer(template, "anny") is first


def test_pose_specs(draper, anny_body):
    rest = draper.poses("rest")[0].pose
    assert rest.shape == (1, anny_body.num_joints, 3)
    assert len(draper.poses(np.zeros((2, anny_body.num_joints, 3)))) == 2
    assert draper.poses("random:3")[0].label == "random:3"
    default = draper.poses()  # the default preset, posed once and then reused like a named one
    assert default[0].label == "relaxed" and torch.equal(default[0].pose, draper.poses("relaxed")[0].pose)
    assert draper.poses(None)[0].pose is default[0].pose


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"material": "velvet"}, "silk, cotton, denim, leather"),
        ({"pose": "dance"}, "choose one of rest, a-pose"),
        ({"shape": {"weight": 1.5}}, r"outside \[0, 1\]"),
        ({"shape": {"wieght": 0.5}}, "unknown phenotypes"),
        ({"pose": np.zeros((3, 3))}, "axis-angles of shape"),
        ({"garments": "no/such/file.obj"}, "no such file"),
        ({"garments": "hoodie:3"}, "CATEGORY:SEED"),
    ],
)
def test_bad_input_names_problem_and_fix(draper, kwargs, pattern):
    garments = kwargs.pop("garments", "default")
    with pytest.raises(DrapeError, match=pattern):
        draper.drape(garments, **kwargs)


def test_garment_in_centimetres_is_refused_naming_units(draper):
    from physdrape.garments import default_garment

    g = default_garment()
    with pytest.raises(DrapeError, match='metres and it looks like centimetres: pass units="cm"'):
        draper.drape((g.verts * 100.0, g.faces))


def test_missing_checkpoint_says_how_to_get_one(tmp_path, monkeypatch):
    monkeypatch.setattr(checkpoint, "bundled_model", lambda: tmp_path / "nothing")
    with pytest.raises(DrapeError, match="physdrape train"):
        Draper()
    with pytest.raises(DrapeError, match="does not exist"):
        Draper(tmp_path / "missing")


def test_save_is_complete_and_refuses_overwrite(draper, tmp_path):
    [res] = draper.drape("default")
    written = res.save(tmp_path)
    assert sorted(p.name for p in written) == sorted(
        ["garment.obj", "body.obj", "garment.ply", "body.ply", "drape.glb"])
    import trimesh

    back = trimesh.load(tmp_path / "garment.ply", process=False)
    np.testing.assert_allclose(back.vertices, res.verts, atol=1e-6)
    with pytest.raises(Exception, match="--force"):
        res.save(tmp_path)
    res.save(tmp_path, formats=("obj",), overwrite=True)


def test_pictures(draper, tmp_path):
    from physdrape.render import convergence_figure, material_sweep_figure

    [res] = draper.drape("default", keep_trace=True)
    assert len(res.convergence["energy"]) == draper.steps + 1
    assert res.convergence["force"][-1] < res.convergence["force"][0]
    assert res.render(tmp_path / "r.png", size=64).stat().st_size > 1000
    assert res.render(tmp_path / "h.png", mode="residual", size=64).is_file()
    assert convergence_figure(res, tmp_path / "c.png").is_file()
    assert material_sweep_figure([res, res], ["a", "b"], tmp_path / "m.png", size=64).is_file()


README = Path(__file__).resolve().parents[2] / "README.md"


def test_readme_example_runs(tiny_checkpoint, anny_body, tmp_path, monkeypatch):
    """The README's Python API block runs as written (and the API docstring shows the same code)."""
    match = re.search(r"## Python API\n\n```python\n(.*?)```", README.read_text(), re.DOTALL)
    code = match.group(1)
    doc = re.search(r"Example.*?::\n\n(.*?)\n\n(?=Conventions)", api.__doc__, re.DOTALL)
    assert textwrap.dedent(doc.group(1)).strip() == code.strip(), "README and api docstring examples differ"
    monkeypatch.setattr(checkpoint, "bundled_model", lambda: Path(tiny_checkpoint))
    monkeypatch.chdir(tmp_path)
    exec(compile(code, "README", "exec"), {})  # noqa: S102 - the snippet is our own docstring
    assert (tmp_path / "out" / "drape.glb").is_file() and (tmp_path / "out" / "render.png").is_file()


def test_module_level_drape_reuses_one_draper(tiny_checkpoint, anny_body, monkeypatch):
    import physdrape

    monkeypatch.setattr(checkpoint, "bundled_model", lambda: Path(tiny_checkpoint))
    monkeypatch.setattr(api.draper, "_DEFAULT_DRAPER", None)
    [a] = physdrape.drape("default", pose="rest")
    first = api.draper._DEFAULT_DRAPER
    [b] = physdrape.drape("default", pose="rest")
    assert api.draper._DEFAULT_DRAPER is first and physdrape.Draper is Draper
    np.testing.assert_array_equal(a.verts, b.verts)


def test_refine_polishes_with_the_oracle(draper):
    [plain] = draper.drape("default")
    [polished] = draper.drape("default", refine=True, refine_iters=1)
    assert np.isfinite(polished.verts).all() and np.abs(polished.verts - plain.verts).max() > 1e-6
    assert polished.timings["refine_s"] > 0


def test_float64_follows_the_draper_dtype(anny_body, tiny_checkpoint):
    [res] = Draper(tiny_checkpoint, steps=1, body=anny_body, dtype=torch.float64).drape("default")
    assert res.verts.dtype == np.float64 and res.body_verts.dtype == np.float64


def test_pose_with_arms_through_the_torso_is_refused(draper, anny_body):
    pose = torch.zeros(anny_body.num_joints, 3, dtype=torch.float64)
    pose[anny_body.joint_index("upperarm01.L"), 2] = -1.2  # both upper arms swung into the chest
    pose[anny_body.joint_index("upperarm01.R"), 2] = 1.2
    with pytest.raises(DrapeError, match="arms through the torso.*choose another pose"):
        draper.drape("default", pose=pose.numpy())
    unchecked = Draper(draper.checkpoint, check_pose=False)
    assert len(unchecked.drape("default", pose=pose.numpy())) == 1


def test_passes_override_the_checkpoints(anny_body, tiny_checkpoint, monkeypatch):
    """Draper(passes=k) runs the network k times before the solver (`PhysDrape.forward` reads each
    pass's inputs at the garment the passes before it moved); by default as many as the
    checkpoint makes."""
    from physdrape.model.physdrape import PhysDrape

    default = Draper(tiny_checkpoint, steps=1, body=anny_body)
    twice = Draper(tiny_checkpoint, steps=1, body=anny_body, passes=2)
    assert default.model_config.passes == 1 and twice.model_config.passes == 2
    looked_at, original = [], PhysDrape._graph_inputs  # what each pass of `forward` reads its inputs with

    def graph_inputs(self, batch, x=None):
        looked_at.append(batch.x_init if x is None else x)
        return original(self, batch, x)

    monkeypatch.setattr(PhysDrape, "_graph_inputs", graph_inputs)
    [once] = default.drape("default")
    assert len(looked_at) == 1
    looked_at.clear()
    [res] = twice.drape("default")
    assert len(looked_at) == 2
    assert res.metrics["b2g_percent"] == 0.0
    with pytest.raises(DrapeError, match="passes must be an integer"):
        Draper(tiny_checkpoint, body=anny_body, passes=0)


def test_follow_planes_overrides_the_checkpoints_setting(anny_body, tiny_checkpoint, monkeypatch):
    """A drape runs the solver's eval-mode plane schedule: by default (`ModelConfig`'s) a full body
    query every eval_requery_every steps and a local one at the steps between;
    Draper(follow_planes=False) holds the planes between full queries every requery_every steps,
    as in training."""
    import physdrape.model.relaxation as relaxation_module

    default = Draper(tiny_checkpoint, steps=10, body=anny_body)
    held = Draper(tiny_checkpoint, steps=10, body=anny_body, follow_planes=False)
    assert default.model_config.eval_follow_planes and default.model_config.eval_requery_every == 8
    assert not held.model_config.eval_follow_planes and not held.model.solver.eval_follow_planes
    assert held.model_config.eval_requery_every == held.model.solver.eval_requery_every == 3  # training's
    assert held.model_config.follow_planes == default.model_config.follow_planes  # training's unchanged
    calls, original = [], relaxation_module.Relaxation.requery

    def requery(self, x, bodies, body_index, **kwargs):
        calls.append(kwargs.get("local", False))
        return original(self, x, bodies, body_index, **kwargs)

    monkeypatch.setattr(relaxation_module.Relaxation, "requery", requery)
    [res] = default.drape("default")
    assert calls == [False, *[True] * 7, False, True] and res.metrics["b2g_percent"] == 0.0
    calls.clear()
    [res] = held.drape("default")
    assert calls == [False, False, False, False] and res.metrics["b2g_percent"] == 0.0  # t = 0, 3, 6, 9


@needs_compiler
def test_compiled_network_drapes_as_the_eager_one(anny_body, tiny_checkpoint):
    """Draper(compile_network=True) runs the network compiled (`EncodeProcessDecode.compile_network`)
    and drapes what the eager Draper drapes, up to float rounding."""
    eager = Draper(tiny_checkpoint, steps=2, body=anny_body)
    compiled = Draper(tiny_checkpoint, steps=2, body=anny_body, compile_network=True)
    assert eager.model.gnn._compiled is None and compiled.model.gnn._compiled is not None
    [want] = eager.drape("default")
    [got] = compiled.drape("default")
    assert compiled.model.gnn._compiled is not None  # it compiled, not fell back
    np.testing.assert_allclose(got.verts, want.verts, atol=1e-5)
    assert got.metrics["b2g_percent"] == 0.0

"""Draping on an SMPL body (a synthetic model in SMPL's file layout, tests/smpl_helpers.py):
β, θ and AMASS frames through the API, warm-started AMASS sequences, and every bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch
from smpl_helpers import write_amass, write_synthetic_smpl, write_torso_band

from physdrape.api import DrapeError, Draper, Motion

pytest.importorskip("smplx")


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("smpl")
    return {"model": write_synthetic_smpl(d / "SMPL_NEUTRAL.npz"), "band": write_torso_band(d / "band.obj"),
            "amass": write_amass(d / "seq.npz", frames=4), "dir": d}


@pytest.fixture(scope="module")
def smpl_draper(files, tiny_checkpoint):
    return Draper(tiny_checkpoint, steps=3, smpl_model=files["model"])


def test_smpl_beta_theta_drape(smpl_draper, files):
    from physdrape.body.smpl_body import SMPLBody

    assert isinstance(smpl_draper.smpl, SMPLBody) and "anny" not in smpl_draper._bodies
    [rest] = smpl_draper.drape(str(files["band"]))
    assert rest.pose == "rest" and rest.body_verts.shape == (162, 3) and np.isfinite(rest.verts).all()
    [shaped] = smpl_draper.drape(str(files["band"]), shape=[2.0, -1.0])  # padded to 10 betas
    assert np.abs(shaped.body_verts - rest.body_verts).max() > 1e-3
    theta = 0.05 * np.ones((2, 24, 3))
    posed = smpl_draper.drape(str(files["band"]), pose=theta)
    assert [r.pose for r in posed] == ["theta[0]", "theta[1]"]
    [flat] = smpl_draper.drape(str(files["band"]), pose=theta[0].reshape(72))
    np.testing.assert_allclose(flat.verts, posed[0].verts, atol=1e-5)
    assert np.abs(flat.body_verts - rest.body_verts).max() > 1e-3
    for r in (rest, shaped, flat):
        assert all(np.isfinite(v) for v in r.metrics.values())
    # a (verts, faces) pair of the file's numbers drapes like the file, and the Draper can be given
    # the body itself (the pair as written: the file rounds it by ~5e-10 m, which float32 solver
    # steps can carry to a visible difference)
    from physdrape.geometry.mesh import read_mesh

    body = SMPLBody(files["model"])
    [pair] = Draper(smpl_draper.checkpoint, steps=3, body=body).drape(read_mesh(files["band"]))
    np.testing.assert_allclose(pair.verts, rest.verts, atol=1e-6)


def test_amass_frames_betas_and_warm_start(smpl_draper, files):
    band = str(files["band"])
    warm = smpl_draper.drape(band, pose=Motion(files["amass"], frames=(0, 4)))
    cold = smpl_draper.drape(band, pose=Motion(files["amass"], frames=(0, 4), warm_start=False))
    assert [r.pose for r in warm] == [f"seq.npz#{k}" for k in range(4)]
    assert [r.init for r in warm] == ["skinning", "warm", "warm", "warm"] and {r.init for r in cold} == {"skinning"}
    np.testing.assert_allclose(warm[0].verts, cold[0].verts, atol=2e-5)
    for w, c in zip(warm[1:], cold[1:]):
        assert np.isfinite(w.verts).all() and np.abs(w.verts - c.verts).max() > 1e-5
        np.testing.assert_allclose(w.body_verts, c.body_verts)
    # the file's betas shape the body, unless shape= is given
    [one] = smpl_draper.drape(band, pose=Motion(files["amass"], frames=2))
    [zero] = smpl_draper.drape(band, pose=Motion(files["amass"], frames=2), shape=[0.0])
    assert one.init == "skinning" and np.abs(one.body_verts - zero.body_verts).max() > 1e-3


def test_warm_start_carries_a_skinned_garment_exactly(smpl_draper, files):
    """Carrying frame t-1's skinned positions by T(t) T(t-1)^-1 gives frame t's X_init (the
    carried positions are strain-limited against frame t's body like the skinned ones)."""
    from dataclasses import replace

    from physdrape.api import sequences
    from physdrape.body.model import BodyState

    template = smpl_draper.garment(str(files["band"]))
    transfer = smpl_draper.transfer(template, "smpl")
    body = smpl_draper.smpl
    poses = 0.1 * torch.randn(2, 24, 3, generator=torch.Generator().manual_seed(0), dtype=torch.float64)
    st = body(torch.full((2, 10), 0.5, dtype=torch.float64), poses)
    singles = [BodyState(verts=st.verts[b:b + 1], faces=st.faces, normals=st.normals[b:b + 1],
                         rest_verts=st.rest_verts[b:b + 1], vertex_transforms=st.vertex_transforms[b:b + 1])
               for b in range(2)]
    x0 = replace(transfer, max_stretch=None).apply(singles[0])[0]
    x1 = transfer.apply(singles[1])[0]
    a0, a1 = (sequences.blended_transforms(transfer, s) for s in singles)
    carried = sequences.carried_init(transfer, x0, a0, a1, singles[1])
    assert (carried - x1).abs().max() < 1e-6


@pytest.mark.parametrize(
    ("kwargs", "pattern"),
    [
        ({"garments": "default"}, "made for the Anny body.*authored on SMPL's canonical body"),
        ({"garments": "tshirt:3"}, "does not fit SMPL"),
        ({"shape": np.zeros(11)}, "11 values, the model 10"),
        ({"shape": [float("nan")]}, "NaN"),
        ({"shape": {"weight": 0.5}}, "shaped by β"),
        ({"pose": np.zeros((23, 3))}, r"shape \(24, 3\) or \(72,\).*got \(23, 3\)"),
        ({"pose": np.full((24, 3), np.nan)}, "NaN"),
        ({"pose": "stand"}, "defined for Anny"),
        ({"pose": "@frames"}, r"out of range: seq.npz has 4 frames"),
        ({"pose": "@noposes"}, "missing 'poses'"),
        ({"pose": "@nanposes"}, "frame 1 contain NaN"),
        ({"pose": "@missing"}, "AMASS file not found"),
        ({"pose": "@bvh"}, "AMASS .npz"),
    ],
)
def test_smpl_bad_inputs(smpl_draper, files, kwargs, pattern):
    d = files["dir"]
    garments = kwargs.pop("garments", str(files["band"]))
    pose = kwargs.get("pose")
    if isinstance(pose, str) and pose.startswith("@"):
        nan = 0.05 * np.ones((3, 156))
        nan[1, 7] = np.nan
        kwargs["pose"] = {
            "@frames": Motion(files["amass"], (2, 9)),
            "@noposes": Motion(write_amass(d / "noposes.npz", poses=None), 0),
            "@nanposes": Motion(write_amass(d / "nan.npz", poses=nan), (0, 3)),
            "@missing": Motion(d / "none.npz", 0),
            "@bvh": Motion(d / "walk.bvh", 0),
        }[pose]
    with pytest.raises(DrapeError, match=pattern):
        smpl_draper.drape(garments, **kwargs)


def test_smpl_model_errors(tiny_checkpoint, files, tmp_path):
    with pytest.raises(DrapeError, match="not shipped.*smpl.is.tue.mpg.de"):
        Draper(tiny_checkpoint, smpl_model=tmp_path / "SMPL_NEUTRAL.npz")
    np.savez(tmp_path / "partial.npz", v_template=np.zeros((3, 3)))
    with pytest.raises(DrapeError, match="missing keys"):
        Draper(tiny_checkpoint, smpl_model=tmp_path / "partial.npz")
    (tmp_path / "model.txt").write_text("x")
    with pytest.raises(DrapeError, match="unknown file type"):
        Draper(tiny_checkpoint, smpl_model=tmp_path / "model.txt")
    with pytest.raises(DrapeError, match="either body"):
        Draper(tiny_checkpoint, smpl_model=files["model"], body=object())


def test_anny_draper_refuses_amass(tiny_checkpoint, files, anny_body):
    with pytest.raises(DrapeError, match="smpl_model"):
        Draper(tiny_checkpoint, body=anny_body).drape("default", pose=Motion(files["amass"], 0))

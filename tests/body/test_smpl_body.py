"""The SMPL backend on a small synthetic model in SMPL's file layout (.npz and legacy .pkl),
the restricted unpickler, and the AMASS loader."""

from __future__ import annotations

import pickle
import sys
import types

import numpy as np
import pytest
import torch

from physdrape.body.model import apply_transforms
from physdrape.body.poses import load_amass_npz

from smpl_helpers import SMPL_PARENTS, synthetic_smpl


@pytest.fixture(scope="module")
def smplx():
    return pytest.importorskip("smplx")


@pytest.fixture
def npz_path(tmp_path):
    path = tmp_path / "SMPL_NEUTRAL.npz"
    np.savez(path, **synthetic_smpl())
    return path


def test_forward_matches_smplx_lbs(smplx, npz_path):
    from smplx.lbs import lbs

    from physdrape.body.smpl_body import SMPLBody

    body = SMPLBody(npz_path)
    assert body.num_joints == 24 and body.num_betas == 10 and body.faces.dtype == torch.int64
    g = torch.Generator().manual_seed(0)
    betas = torch.randn(3, 10, generator=g, dtype=torch.float64)
    theta = 0.5 * torch.randn(3, 72, generator=g, dtype=torch.float64)
    transl = torch.randn(3, 3, generator=g, dtype=torch.float64)
    st = body(betas, theta, transl=transl)
    d = synthetic_smpl()
    dt = torch.float64
    ref, ref_joints = lbs(
        betas, theta, torch.tensor(d["v_template"], dtype=dt), torch.tensor(d["shapedirs"], dtype=dt),
        torch.tensor(d["posedirs"].reshape(-1, d["posedirs"].shape[-1]).T, dtype=dt),
        torch.tensor(d["J_regressor"], dtype=dt), torch.tensor(SMPL_PARENTS), torch.tensor(d["weights"], dtype=dt),
    )
    # smplx's Rodrigues adds 1e-8 to every angle, hence ~1e-8 differences
    assert (st.verts - (ref + transl[:, None])).abs().max() < 1e-6
    assert (st.joints - (ref_joints + transl[:, None])).abs().max() < 1e-6
    # pose correctives folded into the transforms: T(rest) == verts
    assert (apply_transforms(st.vertex_transforms, st.rest_verts) - st.verts).abs().max() < 1e-12
    assert st.verts.shape == (3, 162, 3) and st.vertex_transforms.shape == (3, 162, 4, 4)
    # zero pose, zero shape = the template
    st0 = body(body.default_shape(1), body.rest_pose(1))
    assert (st0.verts[0] - body.canonical_verts()).abs().max() < 1e-6
    assert ((st0.normals[0] * (st0.verts[0] - st0.verts[0].mean(0))).sum(-1) > 0).all()


def test_legacy_pkl_with_chumpy_and_sparse(smplx, tmp_path, monkeypatch):
    """A py2-style SMPL pickle: chumpy arrays (stand-in module) and a sparse J_regressor."""
    import scipy.sparse as sp

    from physdrape.body.smpl_body import SMPLBody

    fake = types.ModuleType("chumpy")
    fake_ch = types.ModuleType("chumpy.ch")

    class Ch:  # pickled like chumpy: class chumpy.ch.Ch, state dict with the array under 'x'
        def __init__(self, x):
            self.x = x

    Ch.__module__, Ch.__qualname__ = "chumpy.ch", "Ch"
    fake_ch.Ch = Ch
    monkeypatch.setitem(sys.modules, "chumpy", fake)
    monkeypatch.setitem(sys.modules, "chumpy.ch", fake_ch)
    d = synthetic_smpl()
    legacy = dict(d, shapedirs=Ch(d["shapedirs"]), posedirs=Ch(d["posedirs"]),
                  J_regressor=sp.csc_matrix(d["J_regressor"]))
    path = tmp_path / "model.pkl"
    path.write_bytes(pickle.dumps(legacy, protocol=2))
    monkeypatch.delitem(sys.modules, "chumpy.ch")
    monkeypatch.delitem(sys.modules, "chumpy")
    body = SMPLBody(path)
    np.savez(tmp_path / "m.npz", **d)
    ref = SMPLBody(tmp_path / "m.npz")
    theta = 0.3 * torch.ones(1, 24, 3)
    assert (body(body.default_shape(1), theta).verts - ref(ref.default_shape(1), theta).verts).abs().max() < 1e-6


class Evil:
    def __reduce__(self):
        import os

        return (os.system, ("echo pwned > /tmp/physdrape_pwned",))


def test_malicious_pickle_refused(smplx, tmp_path):
    from physdrape.body.smpl_body import SMPLBody, load_model_file

    path = tmp_path / "evil.pkl"
    path.write_bytes(pickle.dumps({"v_template": Evil()}))
    with pytest.raises(pickle.UnpicklingError, match=r"refusing to load (posix|os)\.system"):
        SMPLBody(path)
    path.write_bytes(pickle.dumps({"x": __import__("collections").OrderedDict()}))
    with pytest.raises(pickle.UnpicklingError, match="only numpy arrays"):
        load_model_file(path)


def test_smpl_errors(smplx, tmp_path, npz_path, monkeypatch):
    from physdrape.body.smpl_body import SMPLBody

    with pytest.raises(FileNotFoundError, match="not shipped"):
        SMPLBody(tmp_path / "nope.npz")
    with pytest.raises(FileNotFoundError, match="SMPL"):
        SMPLBody(tmp_path / "empty_dir_does_not_exist" / "x.pkl")
    np.savez(tmp_path / "partial.npz", v_template=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="missing keys"):
        SMPLBody(tmp_path / "partial.npz")
    body = SMPLBody(tmp_path)  # a folder holding SMPL_NEUTRAL.npz
    with pytest.raises(ValueError, match=r"betas must have shape \(B, 10\)"):
        body(torch.zeros(1, 9), body.rest_pose(1))
    with pytest.raises(ValueError, match="NaN"):
        body(body.default_shape(1), torch.full((1, 72), float("nan")))
    with pytest.raises(ValueError, match=r"\(B, 24, 3\)"):
        body(body.default_shape(1), torch.zeros(1, 69))
    monkeypatch.setitem(sys.modules, "smplx", None)
    with pytest.raises(ImportError, match="pip install smplx"):
        SMPLBody(npz_path)


def test_amass_loader(tmp_path):
    rng = np.random.default_rng(0)
    poses = 0.2 * rng.standard_normal((5, 156))
    poses[:, :3] = 0.0
    np.savez(tmp_path / "seq.npz", poses=poses, trans=np.tile([0.0, 0.0, 1.0], (5, 1)),
             betas=rng.standard_normal(16), gender="female", mocap_framerate=120.0)
    seq = load_amass_npz(tmp_path / "seq.npz", dtype=torch.float64)
    assert seq["pose"].shape == (5, 24, 3) and seq["betas"].shape == (10,) and seq["fps"] == 120.0
    assert seq["gender"] == "female"
    assert torch.allclose(seq["pose"][:, 1:22], torch.tensor(poses[:, 3:66]).reshape(5, 21, 3))
    assert (seq["pose"][:, 22:] == 0).all()
    # z-up -> y-up: translation (0, 0, 1) becomes (0, 1, 0); identity root becomes -90 deg about x
    assert torch.allclose(seq["transl"], torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand(5, 3), atol=1e-12)
    assert torch.allclose(seq["pose"][0, 0], torch.tensor([-np.pi / 2, 0.0, 0.0], dtype=torch.float64))
    with pytest.raises(FileNotFoundError):
        load_amass_npz(tmp_path / "none.npz")


def test_smplx_layout_55_joints_and_object_entries(smplx, tmp_path):
    """SMPL-X layout: 55 joints, 400 shape+expression directions, an object-array metadata entry
    (as in the official .npz) that is skipped rather than unpickled."""
    from physdrape.body.smpl_body import SMPLBody

    rng = np.random.default_rng(1)
    d = synthetic_smpl()
    V, J = d["v_template"].shape[0], 55
    parents = [-1] + [int(rng.integers(0, j)) for j in range(1, J)]
    d.update(
        shapedirs=0.01 * rng.standard_normal((V, 3, 400)),
        posedirs=0.01 * rng.standard_normal((V, 3, 9 * (J - 1))),
        J_regressor=rng.dirichlet(np.ones(V), size=J),
        weights=rng.dirichlet(np.full(J, 0.3), size=V),
        kintree_table=np.array([[4294967295] + parents[1:], list(range(J))], dtype=np.int64),
        part2num=np.array({"body": 0}, dtype=object),
    )
    np.savez(tmp_path / "SMPLX_NEUTRAL.npz", **d)
    body = SMPLBody(tmp_path / "SMPLX_NEUTRAL.npz")
    assert body.num_joints == 55 and body.num_betas == 10
    st = body(torch.zeros(2, 10, dtype=torch.float64), 0.2 * torch.ones(2, 165, dtype=torch.float64))
    assert st.verts.shape == (2, V, 3)
    assert (apply_transforms(st.vertex_transforms, st.rest_verts) - st.verts).abs().max() < 1e-12


def test_amass_without_trans_and_joint_mapping(tmp_path):
    """Only `poses` is required; SMPL+H hand joints are not copied into SMPL-X's jaw/eyes."""
    rng = np.random.default_rng(2)
    poses = 0.2 * rng.standard_normal((3, 156))
    np.savez(tmp_path / "seq.npz", poses=poses)
    seq = load_amass_npz(tmp_path / "seq.npz", z_up=False, dtype=torch.float64)
    assert seq["transl"].shape == (3, 3) and (seq["transl"] == 0).all() and (seq["betas"] == 0).all()
    x = load_amass_npz(tmp_path / "seq.npz", num_joints=55, z_up=False, dtype=torch.float64)["pose"]
    assert torch.allclose(x[:, :22], torch.tensor(poses[:, :66]).reshape(3, 22, 3)) and (x[:, 22:] == 0).all()
    h = load_amass_npz(tmp_path / "seq.npz", num_joints=52, z_up=False, dtype=torch.float64)["pose"]
    assert torch.allclose(h, torch.tensor(poses).reshape(3, 52, 3))
    np.savez(tmp_path / "bad.npz", trans=np.zeros((3, 3)))
    with pytest.raises(ValueError, match="missing 'poses'"):
        load_amass_npz(tmp_path / "bad.npz")


def test_rig_names_and_parts(smplx, npz_path):
    from physdrape.body.smpl_body import SMPLBody

    body = SMPLBody(npz_path)
    assert body.rig == "smpl"
    part = body.vertex_part()
    assert part.shape == (body.num_verts,) and int(part.max()) < body.num_joints

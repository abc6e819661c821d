import numpy as np
import pytest
import scipy.io

from physdrape.garments import list_cloth3d_garments, load_cloth3d_garment
from physdrape.geometry.mesh import MeshError


def _write_sample(d):
    d.mkdir()
    scipy.io.savemat(str(d / "info.mat"), {
        "outfit": {"Top": {"fabric": "cotton", "texture": {"type": "color"}},
                   "Trousers": {"fabric": "denim", "texture": {"type": "color"}}},
        "gender": 0, "shape": np.linspace(-1, 1, 10), "zrot": 0.5,
    })
    # a quad strip, the way CLOTH3D stores its garments (with texture indices)
    (d / "Top.obj").write_text(
        "v 0 1.2 0\nv 0.1 1.2 0\nv 0.2 1.2 0\nv 0 1.0 0\nv 0.1 1.0 0\nv 0.2 1.0 0\n"
        "vt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 4/4 5/3 2/2\nf 2/1 5/4 6/3 3/2\n")
    (d / "Trousers.obj").write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\nf 1 2 3\n")


def test_load_cloth3d_top(tmp_path):
    s = tmp_path / "01_01_s0"
    _write_sample(s)
    assert list_cloth3d_garments(s) == ["Top", "Trousers"]
    assert list_cloth3d_garments(s, upper_body_only=True) == ["Top"]
    g = load_cloth3d_garment(s)
    assert g.faces.shape == (4, 3) and g.verts.shape == (6, 3)
    assert g.meta["fabric"] == "cotton" and g.meta["gender"] == 0
    np.testing.assert_allclose(g.meta["shape"], np.linspace(-1, 1, 10))
    assert load_cloth3d_garment(s, "Trousers").num_faces == 1


def test_cloth3d_errors(tmp_path):
    with pytest.raises(MeshError, match="info.mat"):
        load_cloth3d_garment(tmp_path)
    s = tmp_path / "x"
    _write_sample(s)
    with pytest.raises(MeshError, match="no garment 'Dress'"):
        load_cloth3d_garment(s, "Dress")
    (s / "Top.obj").unlink()
    with pytest.raises(MeshError, match="not found"):
        load_cloth3d_garment(s, "Top")

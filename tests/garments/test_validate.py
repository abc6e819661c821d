import numpy as np
import pytest

from physdrape.garments import GarmentError, load_template, validate_garment, write_ply
from physdrape.garments.io import read_ply
from physdrape.geometry.mesh import MeshError


def _sheet(n=6, size=0.3, y=0.0):
    xs = np.linspace(0, size, n)
    v = np.array([[x, y, z] for z in xs for x in xs], float)
    f = []
    for r in range(n - 1):
        for c in range(n - 1):
            a = r * n + c
            f += [[a, a + n, a + 1], [a + 1, a + n, a + n + 1]]
    return v, np.array(f)


def test_clean_sheet_is_ok():
    v, f = _sheet()
    r = validate_garment(v, f, body=False)
    assert r.ok, str(r)
    assert r.num_boundary_loops == 1 and r.num_components == 1 and r.euler == 1
    assert "OK" in str(r) and "boundary loops 1" in str(r)


def test_wrong_units_is_an_error(tmp_path):
    v, f = _sheet()
    r = validate_garment(v * 100, f, body=False)  # centimetres
    assert not r.ok and "not metres" in str(r)
    path = tmp_path / "cm.obj"
    path.write_text("".join(f"v {a} {b} {c}\n" for a, b, c in v * 100)
                    + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in f))
    with pytest.raises(GarmentError, match="scale by 0.01"):
        load_template(path, body=False)


def test_missing_file_is_a_clear_error(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        load_template(tmp_path / "nope.obj")
    with pytest.raises(MeshError, match="not found"):
        read_ply(tmp_path / "nope.ply")


def test_non_manifold_edge_is_named():
    v, f = _sheet(3)
    extra = np.array([[0.05, 0.2, 0.05]])
    v2 = np.concatenate([v, extra])
    f2 = np.concatenate([f, [[f[0, 1], f[0, 2], len(v)]]])  # a third face on an interior edge
    r = validate_garment(v2, f2, body=False)
    assert not r.ok
    a, b = sorted(f[0, 1:])
    assert f"({a}, {b})" in str(r)
    with pytest.raises(GarmentError, match="more than two faces"):
        r.raise_if_failed()


def test_bow_tie_vertex_and_degenerate_face():
    v = np.array([[0, 0, 0], [0.1, 0, 0], [0, 0.1, 0], [-0.1, 0, 0], [0, -0.1, 0], [0.2, 0, 0]], float)
    f = np.array([[0, 1, 2], [0, 3, 4]])  # two triangles touching only at vertex 0
    r = validate_garment(v, f, body=False)
    assert list(r.non_manifold_verts) == [0] and not r.ok
    r = validate_garment(v, np.array([[0, 1, 5]]), body=False)  # collinear
    assert list(r.degenerate_faces) == [0] and not r.ok


def test_malformed_arrays_raise():
    with pytest.raises(GarmentError, match=r"\(V, 3\)"):
        validate_garment(np.zeros((3, 2)), np.zeros((1, 3), int), body=False)
    with pytest.raises(GarmentError, match="outside"):
        validate_garment(np.zeros((3, 3)), np.array([[0, 1, 7]]), body=False)


def test_self_intersection_detected():
    v1, f1 = _sheet(4, 0.2)
    v2 = v1[:, [1, 0, 2]] + [0.1, -0.1, 0.0]  # a sheet crossing the first one
    v = np.concatenate([v1, v2])
    f = np.concatenate([f1, f1 + len(v1)])
    r = validate_garment(v, f, body=False)
    assert r.self_intersecting_faces is not None and len(r.self_intersecting_faces) > 0
    assert "self-intersecting" in str(r)


@pytest.mark.anny
def test_penetration_detected(body):
    chest = body.verts[np.argmax(body.verts[:, 2] * (np.abs(body.verts[:, 1] - 0.35) < 0.02))]
    v, f = _sheet(5, 0.1)
    v = v[:, [0, 2, 1]]  # upright, facing +z
    v = v - v.mean(0) + chest - [0, 0, 0.01]  # a small sheet cutting into the chest
    r = validate_garment(v, f, body=(body.verts, body.faces))
    assert len(r.inside_verts) > 0 and 0 < r.inside_area_fraction < 1 and not r.ok
    r2 = validate_garment(v + [0, 0, 0.06], f, body=(body.verts, body.faces))
    assert r2.ok, str(r2)


def test_ply_roundtrip_is_exact_and_deterministic(tmp_path):
    v, f = _sheet()
    h1 = write_ply(tmp_path / "a.ply", v, f)
    h2 = write_ply(tmp_path / "b.ply", v.copy(), f.copy())
    assert h1 == h2 and (tmp_path / "a.ply").read_bytes() == (tmp_path / "b.ply").read_bytes()
    u, g = read_ply(tmp_path / "a.ply")
    assert np.array_equal(u, v) and np.array_equal(g, f)
    g2 = load_template(tmp_path / "a.ply", body=False)  # through geometry.mesh.read_mesh (trimesh)
    assert np.array_equal(g2.faces, f) and np.allclose(g2.verts, v)


def test_obj_quads_are_triangulated(tmp_path):
    p = tmp_path / "quad.obj"
    p.write_text("v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nf 1 2 3 4\n")
    g = load_template(p, body=False)
    assert g.faces.shape == (2, 3)

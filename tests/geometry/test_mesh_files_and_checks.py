"""Reading garment meshes keeps their topology; bad meshes get errors that name the culprits."""

import numpy as np
import pytest
import torch

from physdrape.geometry import topology
from physdrape.geometry.garment import Garment, GarmentBatch, vertex_normals
from physdrape.geometry.mesh import MeshError, check_mesh, read_mesh, write_mesh
from physdrape.geometry.primitives import grid_sheet, open_cylinder


def test_obj_keeps_vertex_order_and_triangulates_polygons(tmp_path):
    path = tmp_path / "quad.obj"
    path.write_text(
        "# a quad and a triangle, with uv and normal indices and a duplicate vertex position\n"
        "v 0 0 0\nv 0.1 0 0\nv 0.1 0 0.1\nv 0 0 0.1\nv 0 0 0\n"
        "vt 0 0\nvn 0 1 0\n"
        "f 1/1/1 2/1/1 3/1/1 4/1/1\n"
        "f -1 -4 -3\n"
    )
    verts, faces = read_mesh(path)
    assert verts.shape == (5, 3) and verts.dtype == np.float64
    np.testing.assert_array_equal(verts[4], [0, 0, 0])  # not merged with vertex 0
    np.testing.assert_array_equal(faces, [[0, 1, 2], [0, 2, 3], [4, 1, 2]])


@pytest.mark.parametrize("suffix", [".obj", ".ply"])
def test_write_then_read_round_trip(tmp_path, suffix):
    verts, faces = open_cylinder(4, 7)
    path = tmp_path / f"tube{suffix}"
    write_mesh(path, verts, faces)
    back_v, back_f = read_mesh(path)
    np.testing.assert_allclose(back_v, verts, rtol=1e-7, atol=1e-9)
    np.testing.assert_array_equal(back_f, faces)
    assert not list(tmp_path.glob(".*")), "no temporary file left behind"


def test_unreadable_inputs(tmp_path):
    with pytest.raises(MeshError, match="not found"):
        read_mesh(tmp_path / "missing.obj")
    (tmp_path / "garment.stl").write_text("solid x\nendsolid x\n")
    with pytest.raises(MeshError, match="use .obj or .ply"):
        read_mesh(tmp_path / "garment.stl")
    (tmp_path / "empty.obj").write_text("v 0 0 0\n")
    with pytest.raises(MeshError, match="no faces"):
        read_mesh(tmp_path / "empty.obj")


def sheet():
    return grid_sheet(3, 3, width=0.2, height=0.2)


def test_nan_vertices_are_named():
    verts, faces = sheet()
    verts[4] = np.nan
    with pytest.raises(MeshError, match=r"vertices 4 have NaN"):
        check_mesh(verts, faces)


def test_out_of_range_faces_are_named():
    verts, faces = sheet()
    faces[3, 1] = 99
    with pytest.raises(MeshError, match=r"faces 3 index vertices outside \[0, 9\)"):
        check_mesh(verts, faces)


def test_degenerate_faces_are_named():
    verts, faces = sheet()
    a, b, c = faces[0]
    verts[c] = 0.5 * (verts[a] + verts[b])  # face 0 collapses onto a line
    with pytest.raises(MeshError, match=r"faces 0\b.*zero rest area"):
        check_mesh(verts, faces)
    faces[0] = [1, 1, 2]
    with pytest.raises(MeshError, match="faces 0 repeat a vertex"):
        check_mesh(*sheet()[:1], faces)


def test_non_manifold_edge_is_named():
    verts, faces = sheet()
    verts = np.vstack([verts, [[0.05, 0.1, 0.05]]])
    a, b = topology.interior_hinges(faces)[0, :2]
    faces = np.vstack([faces, [[a, b, 9]]])  # a third face on the interior edge (a, b)
    with pytest.raises(MeshError, match=rf"non-manifold.*\({min(a, b)}, {max(a, b)}\)"):
        check_mesh(verts, faces)


def test_centimetres_are_refused_with_the_fix():
    verts, faces = sheet()
    with pytest.raises(MeshError, match="scale it by 0.01"):
        check_mesh(verts * 850.0, faces, name="shirt.obj")


def test_garment_rest_quantities():
    verts, faces = grid_sheet(4, 5, width=0.4, height=0.3)
    g = Garment.from_mesh(verts, faces)
    assert g.num_verts == 20 and g.num_faces == 24
    assert torch.allclose(g.rest_area.sum(), torch.tensor(0.12, dtype=torch.float64))
    # Dm⁻¹ maps each rest triangle's edges to an orthonormal frame: (Dm⁻¹)ᵀ Ds_restᵀ Ds_rest Dm⁻¹ = I.
    f = g.faces
    ds = torch.stack([g.rest[f[:, 1]] - g.rest[f[:, 0]], g.rest[f[:, 2]] - g.rest[f[:, 0]]], dim=-1)
    F = ds @ g.rest_inv
    torch.testing.assert_close(F.transpose(-1, -2) @ F, torch.eye(2, dtype=torch.float64).expand(24, 2, 2))
    assert len(g.edges) == 43 and len(g.hinges) == 24 * 3 // 2 - 7 and len(g.boundary_loops) == 1
    assert len(g.boundary_loops[0]) == 2 * (4 + 5) - 4
    n = vertex_normals(g.rest, g.faces)
    torch.testing.assert_close(n, torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64).expand(20, 3))


def test_batch_offsets_and_edge_index():
    a = Garment.from_mesh(*grid_sheet(3, 3))
    b = Garment.from_mesh(*open_cylinder(3, 5))
    batch = GarmentBatch.pack([a, b])
    assert batch.vert_offsets.tolist() == [0, 9, 24]
    assert batch.faces[len(a.faces):].min() == 9
    assert batch.edge_index.shape == (2, 2 * (len(a.edges) + len(b.edges)))
    # Row 0 is the sender; every edge appears in both directions.
    pairs = set(map(tuple, batch.edge_index.T.tolist()))
    assert all((j, i) in pairs for i, j in pairs)
    assert batch.vert_garment.tolist() == [0] * 9 + [1] * 15
    with pytest.raises(ValueError, match="share a dtype"):
        GarmentBatch.pack([a, b.to(torch.float32)])

"""Drape results written to files: the glTF scene read back by an independent reader (trimesh), the
PLY bit for bit, and saving a drape without importing a mesh library."""

from __future__ import annotations

import io
import subprocess
import sys
from types import SimpleNamespace

import numpy as np
import pytest
import trimesh

from physdrape.export import BODY_RGBA, GARMENT_RGBA, glb_bytes, save_result
from physdrape.garments.numpy_geometry import vertex_normals
from physdrape.geometry.mesh import MeshError, read_mesh
from physdrape.geometry.primitives import grid_sheet, open_cylinder


def result():
    garment, faces = grid_sheet(4, 5, width=0.3, height=0.2)
    body, body_faces = open_cylinder(6, 9)
    return SimpleNamespace(verts=garment + np.array([0.0, 1.0, 0.1]), faces=faces, body_verts=body,
                           body_faces=body_faces)


def test_glb_scene_read_back_by_trimesh(tmp_path):
    r = result()
    save_result(r, tmp_path, formats=["glb"])
    scene = trimesh.load(tmp_path / "drape.glb", file_type="glb", process=False)
    assert sorted(scene.geometry) == ["body", "garment"]
    for name, verts, faces, rgba in (("body", r.body_verts, r.body_faces, BODY_RGBA),
                                     ("garment", r.verts, r.faces, GARMENT_RGBA)):
        mesh = scene.geometry[name]
        np.testing.assert_allclose(mesh.vertices, verts, atol=1e-6)  # float32 positions
        np.testing.assert_array_equal(mesh.faces, faces)
        np.testing.assert_array_equal(mesh.visual.material.baseColorFactor, rgba)
        np.testing.assert_allclose(mesh.vertex_normals, vertex_normals(verts, faces), atol=1e-6)
    flat = scene.geometry["garment"].vertex_normals
    assert np.allclose(np.abs(flat), np.abs(flat[0]), atol=1e-6), "a flat sheet: one normal everywhere"


def test_glb_layout_is_aligned_and_sized():
    data = glb_bytes([("a", *open_cylinder(4, 5), (1, 2, 3, 255))])
    magic, version, length = np.frombuffer(data[:12], "<u4")
    assert (magic, version, length) == (0x46546C67, 2, len(data)) and len(data) % 4 == 0
    json_length = int(np.frombuffer(data[12:16], "<u4")[0])
    assert json_length % 4 == 0 and data[20 + json_length + 4: 20 + json_length + 8] == b"BIN\0"
    assert len(trimesh.load(io.BytesIO(data), file_type="glb").geometry) == 1


def test_glb_refuses_an_empty_mesh():
    with pytest.raises(MeshError, match="no vertices or no faces"):
        glb_bytes([("garment", np.zeros((0, 3)), np.zeros((0, 3), np.int64), GARMENT_RGBA)])


def test_ply_is_bit_for_bit(tmp_path):
    r = result()
    save_result(r, tmp_path, formats=["ply"])
    verts, faces = read_mesh(tmp_path / "garment.ply")
    np.testing.assert_array_equal(verts, r.verts)
    np.testing.assert_array_equal(faces, r.faces)


def test_saving_a_drape_imports_no_mesh_library(tmp_path):
    code = ("import sys, numpy as np; from types import SimpleNamespace as S; from physdrape.export import save_result;"
            "from physdrape.geometry.primitives import grid_sheet; v, f = grid_sheet(3, 3, width=0.2, height=0.2);"
            f"save_result(S(verts=v, faces=f, body_verts=v + 1, body_faces=f), {str(tmp_path)!r});"
            "print('trimesh' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "False"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["garment.obj", "body.obj", "garment.ply", "body.ply", "drape.glb"])

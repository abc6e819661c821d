"""The body surface's face, edge and vertex normals (Warp kernels) against their torch twin."""

import numpy as np
import pytest
import torch
import trimesh
from device_params import DEVICES
from surface_normals_reference import surface_normals as reference

from physdrape.geometry.primitives import grid_sheet
from physdrape.geometry.surface_normals import surface_normals
from physdrape.geometry.topology import edge_neighbour_faces


def _case(verts: np.ndarray, faces: np.ndarray, device: str = "cpu"):
    neighbours = torch.from_numpy(edge_neighbour_faces(faces)).to(device=device, dtype=torch.int32)
    return torch.as_tensor(faces, device=device).to(torch.int32), neighbours


@pytest.mark.parametrize("device", DEVICES)
def test_kernels_match_the_torch_twin_on_closed_and_open_meshes(device):
    """Two posed copies of a sphere (closed), a sheet with a hole's border edges, a degenerate
    face and a vertex in no face: the same normals as the torch twin, float64."""
    sphere = trimesh.creation.icosphere(subdivisions=2, radius=0.1)
    verts = torch.tensor(np.asarray(sphere.vertices))
    two = torch.stack([verts, verts * torch.tensor([1.0, 1.3, 0.8], dtype=torch.float64) + 0.05])
    sheet_v, sheet_f = grid_sheet(4, 5, width=0.3, height=0.2)
    sheet_v = torch.as_tensor(sheet_v, dtype=torch.float64)
    sheet_v[7, 1] += 0.05  # not flat
    degenerate = np.vstack([sheet_f, [[0, 1, 2]]])  # collinear corners on the sheet's first row
    lone = torch.cat([sheet_v, torch.tensor([[1.0, 1.0, 1.0]], dtype=torch.float64)])[None]
    for verts_b, faces in ((two, np.asarray(sphere.faces)), (lone, degenerate)):
        faces32, neighbours = _case(verts_b.numpy()[0], faces, device)
        got = surface_normals(verts_b.to(device), faces32, neighbours)
        want = reference(verts_b, faces32.cpu(), neighbours.cpu())
        for g, w in zip(got, want):
            assert g.dtype == torch.float64 and g.device.type == torch.device(device).type
            torch.testing.assert_close(g.cpu(), w, rtol=0, atol=1e-12)
    face, _, vertex = got
    assert not bool(face[0, -1].any()) and not bool(vertex[0, -1].any())  # the degenerate face, the lone vertex
    assert bool((neighbours < 0).any())  # border edges were tested

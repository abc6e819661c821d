import numpy as np
import pytest

from physdrape.garments import remesh
from physdrape.garments.remesh import mean_edge_length
from physdrape.geometry.topology import boundary_loops, connected_components, undirected_edges


def _euler(v, f):
    return len(np.unique(f)) - len(undirected_edges(f)) + len(f)


def _cylinder(rings=4, segments=12, radius=0.15, length=0.4):
    """A coarse open tube with irregular rings (two boundary loops)."""
    th = np.linspace(0, 2 * np.pi, segments, endpoint=False)
    ys = np.array([0.0, 0.05, 0.22, 0.4])[:rings]
    v = np.array([[radius * np.cos(t), y, radius * np.sin(t)] for y in ys for t in th])
    f = []
    for r in range(rings - 1):
        for s in range(segments):
            a, b = r * segments + s, r * segments + (s + 1) % segments
            f += [[a, b, b + segments], [a, b + segments, a + segments]]
    return v, np.array(f)


def test_remesh_keeps_boundary_loops_and_topology():
    v, f = _cylinder()
    u, g = remesh(v, f, target_edge=0.02)
    assert len(boundary_loops(g)) == len(boundary_loops(f)) == 2
    assert _euler(u, g) == _euler(v, f) == 0
    assert len(np.unique(connected_components(len(u), g))) == 1
    assert abs(mean_edge_length(u, g) - 0.02) < 0.005
    # the boundary stays on the original rims (y = 0 and y = 0.4, radius 0.15)
    for loop in boundary_loops(g):
        y = u[loop, 1]
        assert np.ptp(y) < 1e-9 and (abs(y[0]) < 1e-9 or abs(y[0] - 0.4) < 1e-9)
        np.testing.assert_allclose(np.hypot(u[loop, 0], u[loop, 2]), 0.15, atol=0.005)


def test_remesh_two_components_and_is_deterministic():
    v, f = _cylinder()
    v2 = np.concatenate([v, v + [1.0, 0, 0]])
    f2 = np.concatenate([f, f + len(v)])
    a = remesh(v2, f2, target_edge=0.03)
    b = remesh(v2, f2, target_edge=0.03)
    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
    assert len(np.unique(connected_components(len(a[0]), a[1]))) == 2
    assert len(boundary_loops(a[1])) == 4 and _euler(*a) == 0


@pytest.mark.anny
def test_remesh_generated_garment_coarser(small_batch):
    g = small_batch[0]
    u, h = remesh(g.verts, g.faces, target_edge=0.03)
    assert len(boundary_loops(h)) == 4 and _euler(u, h) == _euler(g.verts, g.faces) == -2
    assert len(u) < g.num_verts / 2.5


def test_remesh_rejects_bad_target():
    v, f = _cylinder()
    with pytest.raises(ValueError, match="target_edge"):
        remesh(v, f, target_edge=0.0)

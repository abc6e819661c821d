"""Shared test helpers (imported by tests/api, tests/cli and tests/body/test_smpl_body.py): a small
synthetic model in SMPL's file layout, a garment band around its torso and a tiny AMASS file.

SMPL models are licensed and never shipped; these files only reproduce the layout."""

from __future__ import annotations

from pathlib import Path

import numpy as np

SMPL_PARENTS = [-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21]


def synthetic_smpl(seed: int = 0) -> dict:
    """An icosphere 'body' (162 vertices) with SMPL's 24-joint layout and random valid data.

    The body is an ellipsoid with semi-axes 0.3 (x), 0.75 (y), 0.18 (z) m around the origin."""
    import trimesh

    rng = np.random.default_rng(seed)
    m = trimesh.creation.icosphere(subdivisions=2, radius=0.3)
    V, J = len(m.vertices), 24
    v_template = np.array(m.vertices) * np.array([1.0, 2.5, 0.6])
    weights = rng.dirichlet(np.full(J, 0.3), size=V)
    J_reg = rng.random((J, V)) * (rng.random((J, V)) < 0.1)
    J_reg[:, 0] += 1e-3
    J_reg /= J_reg.sum(1, keepdims=True)
    kintree = np.array([[4294967295] + SMPL_PARENTS[1:], list(range(J))], dtype=np.int64)
    return {
        "v_template": v_template,
        "shapedirs": 0.01 * rng.standard_normal((V, 3, 10)),
        "posedirs": 0.01 * rng.standard_normal((V, 3, 9 * (J - 1))),
        "J_regressor": J_reg,
        "weights": weights,
        "kintree_table": kintree,
        "f": np.array(m.faces, dtype=np.uint32),
    }


def write_synthetic_smpl(path: str | Path, seed: int = 0) -> Path:
    path = Path(path)
    np.savez(path, **synthetic_smpl(seed))
    return path


def torso_band(around: int = 24, rows: int = 6, *, clearance: float = 1.08) -> tuple[np.ndarray, np.ndarray]:
    """An open elliptic tube (a 'skirt' band, y in [-0.2, 0.2] m) `clearance` times the synthetic
    body's waist: verts (V, 3) [m], faces (F, 3)."""
    ang = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    ys = np.linspace(0.2, -0.2, rows)
    verts = np.array([[clearance * 0.3 * np.cos(a), y, clearance * 0.18 * np.sin(a)] for y in ys for a in ang])
    faces = []
    for r in range(rows - 1):
        for k in range(around):
            a, b = r * around + k, r * around + (k + 1) % around
            c, d = a + around, b + around
            faces += [[a, c, b], [b, c, d]]
    return verts, np.array(faces, dtype=np.int64)


def write_torso_band(path: str | Path) -> Path:
    from physdrape.geometry.mesh import write_mesh

    path = Path(path)
    write_mesh(path, *torso_band())
    return path


def write_amass(path: str | Path, frames: int = 4, *, seed: int = 0, scale: float = 0.05, **extra) -> Path:
    """A small AMASS-style sequence: poses (N, 156) SMPL+H axis-angles, betas (16,), trans (N, 3).
    The root orientation is +90 deg about x, so the z-up -> y-up turn leaves the body upright."""
    rng = np.random.default_rng(seed)
    poses = scale * rng.standard_normal((frames, 156))
    poses[:, :3] = [np.pi / 2, 0.0, 0.0]
    data = {"poses": poses, "betas": 0.5 * rng.standard_normal(16), "trans": np.zeros((frames, 3)),
                "gender": "neutral", "mocap_framerate": 60.0}
    data.update(extra)
    data = {k: v for k, v in data.items() if v is not None}
    path = Path(path)
    np.savez(path, **data)
    return path

"""Garment parts (pieces, waistband, hem) and panel overlaps on small synthetic garments."""

from __future__ import annotations

import numpy as np

from physdrape.garments import closures
from physdrape.garments.closures import panel_overlaps
from physdrape.garments.pieces import garment_parts


def tube(y0: float, y1: float, *, radius: float = 0.15, around: int = 24, rows: int = 6, sweep: float = 2 * np.pi,
         radius_step: float = 0.0, x0: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """A vertical tube (sweep = 2π, closed around) or an open wrap of `sweep` radians whose radius
    grows by `radius_step` per radian (so a wrap beyond 2π lies on itself); y from y0 to y1."""
    closed = np.isclose(sweep, 2 * np.pi)
    cols = around if closed else around + 1
    theta = np.linspace(0.0, sweep, cols, endpoint=not closed)
    verts = []
    for y in np.linspace(y0, y1, rows):
        r = radius + radius_step * theta
        verts.append(np.stack([x0 + r * np.sin(theta), np.full(cols, y), r * np.cos(theta)], 1))
    verts = np.concatenate(verts)
    faces = []
    for i in range(rows - 1):
        for j in range(around):
            a, b = i * cols + j, i * cols + (j + 1) % cols
            c, d = a + cols, b + cols
            faces += [(a, b, d), (a, d, c)]
    return verts, np.asarray(faces, np.int64)


def combine(*meshes):
    verts, faces, offset = [], [], 0
    for v, f in meshes:
        verts.append(v)
        faces.append(f + offset)
        offset += len(v)
    return np.concatenate(verts), np.concatenate(faces)


def test_parts_of_a_top_over_trousers():
    trousers = tube(-0.1, 0.1)
    top = tube(0.05, 0.5, radius=0.16)
    verts, faces = combine(top, trousers)
    parts = garment_parts(verts, faces)
    assert parts.lower == 1
    assert np.allclose(verts[parts.waistband, 1], 0.1)
    assert np.allclose(verts[parts.hem, 1], 0.05)


def test_one_piece_has_no_waistband():
    verts, faces = tube(0.0, 0.5)
    parts = garment_parts(verts, faces)
    assert parts.num_pieces == 1 and parts.lower is None and parts.waistband is None
    assert np.allclose(verts[parts.hem, 1], 0.0)


def test_overlapping_wrap_front_is_found_and_a_closed_tube_is_not():
    verts, faces = tube(0.0, 0.4, sweep=2 * np.pi * 40 / 36, around=40, radius_step=0.003 / (2 * np.pi))
    parts = garment_parts(verts, faces)
    pairs = panel_overlaps(verts, faces, parts.piece)
    assert len(pairs) > 0
    gap = np.linalg.norm(verts[pairs[:, 0]] - verts[pairs[:, 1]], axis=1)
    assert gap.max() < 8e-3
    theta = np.arctan2(verts[pairs].reshape(-1, 3)[:, 0], verts[pairs].reshape(-1, 3)[:, 2])
    assert np.all(np.abs(np.sin(theta)) < np.sin(0.75))  # all where the wrap's ends overlap
    assert len(np.unique(pairs)) == pairs.size  # each vertex in at most one pair

    verts, faces = tube(0.0, 0.4)
    assert len(panel_overlaps(verts, faces, garment_parts(verts, faces).piece)) == 0
    # an excluded piece is never paired
    verts, faces = tube(0.0, 0.4, sweep=2 * np.pi * 40 / 36, around=40, radius_step=0.003 / (2 * np.pi))
    assert len(panel_overlaps(verts, faces, np.zeros(len(verts), np.int64), exclude=np.ones(len(verts), bool))) == 0


def test_the_one_panel_test_in_blocks_of_sources_finds_the_same_pairs(monkeypatch):
    verts, faces = tube(0.0, 0.4, sweep=2 * np.pi * 40 / 36, around=40, radius_step=0.003 / (2 * np.pi))
    piece = garment_parts(verts, faces).piece
    whole = panel_overlaps(verts, faces, piece, radius=0.05)
    monkeypatch.setattr(closures, "_HOP_ROWS", 3 * len(verts))  # three sources per search
    assert len(whole) > 0 and np.array_equal(panel_overlaps(verts, faces, piece, radius=0.05), whole)

"""A drape whose pieces pass through one another says so: its piece crossings in the metrics and
the report, and a warning; a drape of a suit-like outfit that keeps its layers reports none."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from physdrape.api import Draper
from physdrape.api.results import crossings_warned
from physdrape.api.types import DrapeWarning
from physdrape.geometry.primitives import grid_sheet


def two_sheets(offset: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two pieces: a horizontal sheet (xz-plane) and the same sheet turned upright (xy-plane),
    moved by `offset`; centred on each other they cross along a line."""
    v, f = grid_sheet(6, 6, width=0.2, height=0.2)
    v = v - v.mean(0)
    upright = v[:, [0, 2, 1]] + offset
    return np.concatenate([v, upright]), np.concatenate([f, f + len(v)])


def test_crossing_pieces_are_counted_and_warned_of():
    verts, faces = two_sheets(np.zeros(3))
    with pytest.warns(DrapeWarning, match=r"crossed: \d+ face pair\(s\) of two of its pieces intersect"):
        [n] = crossings_warned(["crossed"], [verts], [faces])
    assert n > 0


def test_pieces_apart_or_one_piece_count_nothing():
    apart, faces = two_sheets(np.array([0.0, 0.3, 0.0]))
    sheet, sheet_faces = grid_sheet(6, 6, width=0.2, height=0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DrapeWarning)
        assert crossings_warned(["apart", "sheet"], [apart, sheet], [faces, sheet_faces]) == [0, 0]


def test_an_outfit_drape_reports_its_crossings():
    with warnings.catch_warnings():
        warnings.simplefilter("error", DrapeWarning)
        [res] = Draper().drape("outfit:2", steps=6)
    assert res.metrics["piece_crossings"] == 0 and res.report()["piece_crossings"] == 0

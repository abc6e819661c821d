"""A refitted rest shape keeps every face open (`garments.sizing.relax_collapsed_faces`)."""

from __future__ import annotations

import numpy as np

from physdrape.garments.sizing import MIN_AREA_RATIO, relax_collapsed_faces
from physdrape.geometry.mesh import face_areas
from physdrape.geometry.primitives import grid_sheet


def test_a_collapsed_face_is_reopened_and_the_faces_away_from_it_keep_their_shape():
    template, faces = grid_sheet(12, 12, width=0.2, height=0.2)
    shift = np.array([0.01, 0.02, -0.005])
    moved = template + shift  # a rigid move: nothing to mend
    np.testing.assert_array_equal(relax_collapsed_faces(template, moved, faces), moved)
    # one vertex dragged almost onto the opposite edge of a face around it: a sliver of 3 % of its area
    v = 6 * 12 + 6
    face = faces[(faces == v).any(axis=1)][0]
    opposite = template[face[face != v]].mean(axis=0)
    crushed = moved.copy()
    crushed[v] = moved[v] + 0.97 * (opposite - template[v])
    rest = face_areas(template, faces)
    assert (face_areas(crushed, faces) / rest).min() < 0.1  # not vacuous
    out = relax_collapsed_faces(template, crushed, faces)
    assert (face_areas(out, faces) / rest).min() >= MIN_AREA_RATIO
    # far from the crushed vertex every vertex keeps the displacement it was given
    far = np.linalg.norm(template - template[v], axis=1) > 0.06
    np.testing.assert_array_equal(out[far], crushed[far])
    assert np.linalg.norm(out[v] - (template[v] + shift)) < 0.5 * np.linalg.norm(crushed[v] - (template[v] + shift))

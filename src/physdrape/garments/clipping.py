"""Cutting the garment patch out of the body surface (numpy).

`clip_mesh` keeps the part of a mesh where a per-vertex field is ≥ 0, cut along its zero level
set, and only the largest piece of it; `fill_crease_holes` closes the holes cut at body creases
(armpits, inner elbows) with fans, which the remesher refines and the shrink-wrap turns into webs.
"""

from __future__ import annotations

import numpy as np

from physdrape.geometry.mesh import face_areas
from physdrape.geometry.topology import boundary_loops, connected_components, drop_unused_vertices

__all__ = ["clip_mesh", "fill_crease_holes"]


def clip_mesh(verts: np.ndarray, faces: np.ndarray, phi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The part of a triangle mesh where the per-vertex field `phi` ≥ 0, cut along phi = 0.

    New vertices sit where the edges cross zero (linear interpolation); cut triangles become
    one or two triangles with the input's orientation. Returns (verts, faces) with unused
    vertices dropped.
    """
    phi = np.where(phi == 0.0, 1e-12, phi)
    pos = phi > 0
    npos = pos[faces].sum(1)
    keep = faces[npos == 3]
    cut = faces[(npos == 1) | (npos == 2)]
    # Rotate each cut triangle so its odd-one-out vertex comes first (keeps the orientation).
    p = pos[cut]
    odd = np.where(p.sum(1) == 1, np.argmax(p, 1), np.argmin(p, 1))
    rot = np.stack([cut[np.arange(len(cut)), (odd + k) % 3] for k in range(3)], 1)
    a, b, c = rot[:, 0], rot[:, 1], rot[:, 2]
    # Crossing points on edges ab and ac.
    pairs = np.concatenate([np.stack([a, b], 1), np.stack([a, c], 1)])
    key = np.sort(pairs, 1)
    uniq, inv = np.unique(key, axis=0, return_inverse=True)
    inv = inv.ravel()
    t = phi[uniq[:, 0]] / (phi[uniq[:, 0]] - phi[uniq[:, 1]])
    new_v = verts[uniq[:, 0]] + t[:, None] * (verts[uniq[:, 1]] - verts[uniq[:, 0]])
    nv = len(verts)
    ab = nv + inv[: len(cut)]
    ac = nv + inv[len(cut):]
    single = pos[a]  # the odd vertex is the only one inside: one triangle
    tri1 = np.stack([a, ab, ac], 1)[single]
    two = ~single  # a outside, b and c inside: quad (ab, b, c, ac)
    tri2 = np.stack([ab[two], b[two], c[two]], 1)
    tri3 = np.stack([ab[two], c[two], ac[two]], 1)
    all_v = np.concatenate([verts, new_v])
    all_f = np.concatenate([keep, tri1, tri2, tri3]).astype(np.int64)
    return _largest_component(all_v, all_f)


def _largest_component(verts: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The face-connected component with the largest area, unused vertices dropped."""
    face_label = connected_components(len(verts), faces)[faces[:, 0]]
    keep = face_label == np.bincount(face_label, weights=face_areas(verts, faces)).argmax()
    return drop_unused_vertices(verts, faces[keep])


def fill_crease_holes(verts: np.ndarray, faces: np.ndarray, holes: list) -> tuple[np.ndarray, np.ndarray]:
    """Fill the holes cut at body creases with a fan around each loop's centroid (the remesher
    refines it and the shrink-wrap turns it into a web bridging the crease).

    `holes` lists the (centre [m] (3,), radius [m]) of each cut; the boundary loop whose centroid
    is nearest a centre, and within 1.5 radii of it, is filled. Returns (verts, faces).
    """
    loops = boundary_loops(faces)
    directed = {(int(a), int(b)) for a, b in np.concatenate(
        [faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])}
    new_v, new_f = [verts], [faces]
    nv = len(verts)
    for pit, radius in holes:
        if not loops:
            break
        k = int(np.argmin([np.linalg.norm(verts[l].mean(0) - pit) for l in loops]))
        if np.linalg.norm(verts[loops[k]].mean(0) - pit) > 1.5 * radius:
            continue
        loop = loops.pop(k)
        a, b = int(loop[0]), int(loop[1])
        if (a, b) in directed:  # the faces use a→b, so the fill must run b→a
            loop = loop[::-1]
        new_v.append(verts[loop].mean(0, keepdims=True))
        nxt = np.roll(loop, -1)
        new_f.append(np.stack([loop, nxt, np.full(len(loop), nv)], 1))
        nv += 1
    return np.concatenate(new_v), np.concatenate(new_f).astype(np.int64)

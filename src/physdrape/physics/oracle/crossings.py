"""The oracle's guard against one piece of a garment passing through another.

A multi-piece garment's layer order (`physics.layers`) holds each vertex on its side of the
piece it was paired with, but its energy does not see a piece that is already through another:
once a step has carried a face through a face of another piece, nothing pushes it back, and a
lower-energy equilibrium with the pieces crossed would become the reference every drape is
measured against. `PieceGuard` lets the line search refuse such a step: a trial that makes two
faces of different pieces of one garment intersect where they did not is rejected, as a trial
that moves a vertex into the body is, and the corners of those faces are held in the step
searched instead (the physics has no contact between pieces: where two pieces touch, the rest of
the garment still settles, the touching parts staying where they are, as if they stuck).
"""

from __future__ import annotations

import numpy as np
import torch
from torch import Tensor

from physdrape.geometry.intersections import self_intersecting_pairs
from physdrape.geometry.topology import connected_components


class PieceGuard:
    """The crossings between pieces of the garments of one packed batch.

    Args:
        faces: the batch's triangles (F, 3) int; face_garment: each face's garment (F,) int;
        num_verts: ΣV; num_garments: G.
    Use `of` to get one only where some garment has several pieces (connected components).
    """

    def __init__(self, faces: Tensor, face_garment: Tensor, num_verts: int, num_garments: int) -> None:
        self.faces = faces.cpu().numpy().astype(np.int64)
        piece = connected_components(num_verts, self.faces)
        self.face_piece = piece[self.faces[:, 0]]
        self.face_garment = face_garment.cpu().numpy().astype(np.int64)
        self.num_garments = num_garments
        pieces = {(int(g), int(p)) for g, p in zip(self.face_garment, self.face_piece)}
        counts = np.bincount([g for g, _ in pieces], minlength=num_garments)
        self.multi = torch.from_numpy(counts > 1)  # (G,) garments of several pieces
        self._known: tuple[Tensor, np.ndarray] | None = None  # `known`'s last positions and pairs

    @staticmethod
    def of(faces: Tensor, face_garment: Tensor, num_verts: int, num_garments: int) -> PieceGuard | None:
        """A guard for the batch, or None where every garment is in one piece (nothing to guard)."""
        guard = PieceGuard(faces, face_garment, num_verts, num_garments)
        return guard if bool(guard.multi.any()) else None

    def pairs(self, x: Tensor) -> np.ndarray:
        """The intersecting face pairs at x (ΣV, 3) whose faces lie on two pieces of one garment,
        each encoded as i·F + j (i < j), sorted."""
        found = self_intersecting_pairs(x.detach().cpu().numpy(), self.faces)
        if not len(found):
            return np.zeros(0, np.int64)
        i, j = found[:, 0], found[:, 1]
        keep = (self.face_garment[i] == self.face_garment[j]) & (self.face_piece[i] != self.face_piece[j])
        return np.sort(i[keep] * len(self.faces) + j[keep])

    def known(self, x: Tensor) -> np.ndarray:
        """`pairs` at the positions a step starts from, kept for the next call with the same
        tensor x (a step's line searches, the first and those with vertices held, all start there)."""
        if self._known is None or self._known[0] is not x:
            self._known = (x, self.pairs(x))
        return self._known[1]

    def new_pairs(self, x: Tensor, known: np.ndarray) -> np.ndarray:
        """The face pairs (K, 2) int64 that cross two pieces of one garment at x (ΣV, 3) and are
        not among `known` (`known` of the state the step starts from)."""
        codes = self.pairs(x)
        fresh = codes[~np.isin(codes, known)]
        return np.stack([fresh // len(self.faces), fresh % len(self.faces)], axis=1)

    def garments(self, pairs: np.ndarray) -> Tensor:
        """(G,) bool: the garments that `pairs` (K, 2) (faces) lie on."""
        out = np.zeros(self.num_garments, bool)
        out[self.face_garment[pairs[:, 0]]] = True
        return torch.from_numpy(out)

    def vertices(self, pairs: np.ndarray, num_verts: int) -> Tensor:
        """(ΣV,) bool: the corners of the faces of `pairs` (K, 2)."""
        out = np.zeros(num_verts, bool)
        out[self.faces[pairs.ravel()].ravel()] = True
        return torch.from_numpy(out)

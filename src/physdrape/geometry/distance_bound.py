"""Lower bounds on points' distances to the body from an earlier exact query, so that a later
query asks only about the points that may lie within a threshold of the body, and knows the side
of the body of those that cannot have crossed its surface since.

The signed distance to a closed surface is 1-Lipschitz: a point whose signed distance was d where
it stood, at p, has signed distance at least d − ‖x − p‖ wherever it has moved to, x. A garment's
vertex that was a centimetre off the body and has since moved a few millimetres cannot be within
the collision margin, nor inside, so the collision handler and the drape's metrics need not search
the body for it.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

#: Slack [m] on every bound: the distances come from queries in the body's dtype (float32: about
#: 1e-7 m at body scale); a point whose bound clears a threshold by less is queried anyway.
SLACK = 1e-5


@dataclass(frozen=True)
class DistanceBound:
    """Points (N, 3) [m] and their exact signed distances (N,) [m] to the body there (float64
    each): row i bounds the signed distance of whatever point takes row i's place later."""

    at: Tensor
    distance: Tensor

    @staticmethod
    def of(points: Tensor, distance: Tensor) -> DistanceBound:
        """The bound of a query's points (N, 3) and signed distances (N,) (detached, float64)."""
        return DistanceBound(points.detach().to(torch.float64).clone(), distance.detach().to(torch.float64).clone())

    def lower(self, points: Tensor) -> Tensor:
        """Lower bounds (N,) [m] of the signed distances of `points` (N, 3), float64."""
        if points.shape != self.at.shape:
            raise ValueError(f"points must have the bound's shape {tuple(self.at.shape)}, got {tuple(points.shape)}")
        return self.distance - (points.detach().to(torch.float64) - self.at).norm(dim=-1)

    def sign(self, points: Tensor) -> Tensor:
        """The side of the body each of `points` (N, 3) must be on (N,) int8: +1 outside, −1
        inside, 0 where it may have crossed the surface since (it moved farther than its distance
        was, less `SLACK`). The signed distance is continuous, so a point cannot change sides
        without passing through the surface."""
        if points.shape != self.at.shape:
            raise ValueError(f"points must have the bound's shape {tuple(self.at.shape)}, got {tuple(points.shape)}")
        clearance = self.distance.abs() - (points.detach().to(torch.float64) - self.at).norm(dim=-1)
        side = torch.where(self.distance > 0, 1, -1).to(torch.int8)
        return torch.where(clearance > SLACK, side, torch.zeros_like(side))

    def rows_below(self, points: Tensor, threshold: float) -> Tensor:
        """The rows (int64) of `points` (N, 3) whose signed distance may be below `threshold` [m]
        (every other point is at least that far outside the body)."""
        return torch.nonzero(self.lower(points) < threshold + SLACK)[:, 0]

    def updated(self, rows: Tensor, points: Tensor, distance: Tensor) -> DistanceBound:
        """The bound with rows `rows` replaced by a newer query's points (R, 3) and distances (R,)."""
        at, known = self.at.clone(), self.distance.clone()
        at[rows] = points.detach().to(torch.float64)
        known[rows] = distance.detach().to(torch.float64)
        return DistanceBound(at, known)

    def select(self, rows: Tensor) -> DistanceBound:
        """Rows `rows` (int) alone, in that order."""
        return DistanceBound(self.at[rows], self.distance[rows])

    def part(self, start: int, stop: int) -> DistanceBound:
        """Rows [start, stop) alone."""
        return DistanceBound(self.at[start:stop], self.distance[start:stop])

"""Seeded body-shape sampling: Anny phenotypes over the adult range (the analogue of SMPL's
β ~ U[-3, 3]), with the weight/muscle extremes kept in the draws."""

from __future__ import annotations

import torch
from torch import Tensor

from physdrape.body.anny_body import PHENOTYPE_NAMES

ADULT_AGE_RANGE = (0.6, 1.0)
"""Anny's age anchors: child 1/3, young adult 2/3, old 1; 0.5 is a late teenager."""
ADULT_HEIGHT_RANGE = (0.2, 0.6)
"""Anny's height phenotype spans dwarf to giant: for adults, 0.2 -> 1.43 m (female) / 1.56 m
(male) and 0.6 -> 1.86 m / 2.0 m head-to-sole; 0.5 is 1.76 m / 1.89 m."""


def sample_shapes(
    num: int,
    *,
    seed: int,
    age_range: tuple[float, float] = ADULT_AGE_RANGE,
    height_range: tuple[float, float] = ADULT_HEIGHT_RANGE,
    extreme_prob: float = 0.2,
    dtype: torch.dtype = torch.float32,
) -> Tensor:
    """Draw `num` adult Anny phenotype vectors, reproducibly.

    Every phenotype is uniform on [0, 1] except age and height (uniform on `age_range` and
    `height_range`). With probability
    `extreme_prob` each of weight and muscle is independently snapped to 0 or 1 (the extremes,
    where garments tear or penetrate, stay in every large draw).

    Returns:
        shape (num, 6) in the order `PHENOTYPE_NAMES`, values in [0, 1].
    """
    for name, (lo, hi) in (("age_range", age_range), ("height_range", height_range)):
        if not (0.0 <= lo <= hi <= 1.0):
            raise ValueError(f"{name} must satisfy 0 <= lo <= hi <= 1, got {(lo, hi)}")
    if not (0.0 <= extreme_prob <= 1.0):
        raise ValueError(f"extreme_prob must be in [0, 1], got {extreme_prob}")
    g = torch.Generator().manual_seed(int(seed))
    x = torch.rand(num, len(PHENOTYPE_NAMES), generator=g, dtype=torch.float64)
    for name, (lo, hi) in (("age", age_range), ("height", height_range)):
        k = PHENOTYPE_NAMES.index(name)
        x[:, k] = lo + (hi - lo) * x[:, k]
    for name in ("weight", "muscle"):
        k = PHENOTYPE_NAMES.index(name)
        snap = torch.rand(num, generator=g, dtype=torch.float64) < extreme_prob
        side = (torch.rand(num, generator=g, dtype=torch.float64) < 0.5).to(torch.float64)
        x[:, k] = torch.where(snap, side, x[:, k])
    return x.to(dtype)

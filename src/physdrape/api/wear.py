"""How garments are worn in a `Draper.drape` call: sizing (`garments.sizing`), the waistband's
grip (`physics.grip`), closures (`physics.stitches`, `garments.closures`) and layer order
(`physics.layers`, `garments.layering`): the options checked once per call, and each job's rest
shape and extra terms."""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np
from torch import Tensor

from physdrape.api.types import DrapeError
from physdrape.garments.sizing import Sizing, default_sizing
from physdrape.physics.grip import DEFAULT_GRIP_STIFFNESS
from physdrape.pipeline import DrapePipeline, Job, Template


@dataclass(frozen=True)
class Wear:
    """The checked wear options of one call (see `Draper.drape`): sizing None / "fit" / "fixed",
    grip κ [N/m³] (0: none), closures "auto" / "off" / (K, 2) template vertex pairs, layers
    "auto" / "off"."""

    sizing: str | None
    grip: float
    closures: str | np.ndarray
    layers: str = "auto"

    @staticmethod
    def check(*, sizing, grip, closures, layers, templates: list[Template]) -> Wear:
        """The options of a call, refused with a DrapeError that names the fix."""
        if sizing is not None and sizing not in {s.value for s in Sizing}:
            raise DrapeError(f"sizing must be one of {', '.join(s.value for s in Sizing)} or None (the garment's "
                             f"default), got {sizing!r}")
        if grip is not None and not (isinstance(grip, (int, float)) and not isinstance(grip, bool)
                                     and math.isfinite(grip) and grip >= 0):
            raise DrapeError(f"grip must be a stiffness κ ≥ 0 [N/m³] (0: no grip) or None (the default "
                             f"{DEFAULT_GRIP_STIFFNESS:g}), got {grip!r}")
        if layers is not None and layers not in ("auto", "off"):
            raise DrapeError(f"layers must be 'auto' (the pieces keep the order they have on the canonical body), "
                             f"'off' or None ('auto'), got {layers!r}")
        return Wear(sizing=sizing, grip=DEFAULT_GRIP_STIFFNESS if grip is None else float(grip),
                    closures=_check_closures(closures, templates), layers=layers or "auto")


def _check_closures(closures, templates: list[Template]):
    """closures as "auto", "off" or a validated (K, 2) int64 array of vertex pairs."""
    if closures is None:
        return "auto"
    if isinstance(closures, str):
        if closures not in ("auto", "off"):
            raise DrapeError(f"closures must be 'auto', 'off' or (K, 2) stitched vertex pairs, got {closures!r}")
        return closures
    try:
        pairs = np.asarray(closures)
    except (TypeError, ValueError) as exc:
        raise DrapeError(f"closures: cannot read the stitched vertex pairs: {exc}") from None
    if pairs.ndim != 2 or pairs.shape[1] != 2 or not np.issubdtype(pairs.dtype, np.integer):
        raise DrapeError(f"closures must be (K, 2) integer vertex pairs, got an array of shape {pairs.shape} and dtype "
                         f"{pairs.dtype}")
    pairs = pairs.astype(np.int64)
    if len(pairs) and (pairs[:, 0] == pairs[:, 1]).any():
        raise DrapeError("closures: a vertex cannot be stitched to itself; give pairs of two different vertices")
    for t in templates:
        if len(pairs) and (pairs.min() < 0 or pairs.max() >= t.num_verts):
            raise DrapeError(f"closures: vertex indices must be in [0, {t.num_verts}) for garment {t.name!r} (got "
                             f"{int(pairs.min())}..{int(pairs.max())}); index the template's vertices (an .mhclo is "
                             "remeshed: Draper.garment(path).verts)")
    return pairs


class Wearing:
    """A Draper's worn jobs: each job's rest shape (cached per garment and body shape) and terms."""

    def __init__(self, *, by_binding: bool = True, cache_size: int = 64) -> None:
        self.by_binding = by_binding  # False on SMPL bodies: .mhclo bindings are to Anny
        self.cache_size = cache_size
        self._rests: dict[tuple, np.ndarray] = {}
        self._lock = threading.Lock()  # a batch split between threads shares the cache

    def job(self, template: Template, body: int, material, x_init: Tensor | None, wear: Wear, state,
            shape: Tensor, pipeline: DrapePipeline) -> Job:
        """The pipeline job of `template` on body `body` of the posed `state` (a `BodyState` or a
        `pipeline.PosedBodies`; its shape (1, S))."""
        if isinstance(wear.closures, str):
            stitches = pipeline.closure_pairs(template) if wear.closures == "auto" else None
        else:
            stitches = wear.closures
        return Job(template, body, material, x_init, self.rest(template, wear.sizing, state, body, shape, pipeline),
                   wear.grip, stitches, wear.layers == "auto")

    def rest(self, template: Template, sizing: str | None, state, index: int, shape: Tensor,
             pipeline: DrapePipeline) -> np.ndarray | None:
        """The garment's rest shape [m] (V, 3) on body `index` of `state` (phenotypes or β `shape`
        (1, S)) when it is sized to fit, None when fixed (`garments.sizing`)."""
        mode = default_sizing(template.sizer) if sizing is None else Sizing(sizing)
        if mode is Sizing.FIXED:
            return None
        by_binding = template.sizer is not None and self.by_binding
        key = (template.key, by_binding, tuple(shape.reshape(-1).tolist()))
        with self._lock:
            rest = self._rests.get(key)
        if rest is None:
            rest = template.sizer.rest(shape) if by_binding else pipeline.fitted_rest(template, state, index)
            with self._lock:
                if len(self._rests) >= self.cache_size:  # a manifest may drape thousands of shapes
                    del self._rests[next(iter(self._rests))]
                self._rests[key] = rest
        return rest

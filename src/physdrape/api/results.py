"""A drape batch's results: the metrics of each drape (`physics.metrics`), its piece crossings,
and one `DrapeResult` per job with numpy arrays, whatever device the drape ran on."""

from __future__ import annotations

import warnings

import numpy as np
import torch
from torch import Tensor

from physdrape.api.types import DrapeResult, DrapeWarning
from physdrape.body.model import BodyState
from physdrape.geometry.distance_bound import DistanceBound
from physdrape.geometry.intersections import piece_crossings
from physdrape.physics.metrics import drape_metrics, faces_inside
from physdrape.pipeline import DrapeInput


def crossings_warned(names: list[str], verts: list[np.ndarray], faces: list[np.ndarray]) -> list[int]:
    """Each drape's intersecting face pairs of two different pieces
    (`geometry.intersections.piece_crossings`: one piece passed through another), with a
    `DrapeWarning` for each drape that has any."""
    crossings = [piece_crossings(v, f) for v, f in zip(verts, faces)]
    for name, n in zip(names, crossings):
        if n:
            warnings.warn(f"{name}: {n} face pair(s) of two of its pieces intersect after the drape (one piece "
                          "passed through another); drape with more steps (--steps) or polish it with the oracle "
                          "(--refine), keeping the pieces' layer order (--layers auto, the default)",
                          DrapeWarning, stacklevel=4)
    return crossings


def inside_warned(names: list[str], poses: list[str], b2g_percent: list[float]) -> None:
    """A `DrapeWarning` for each drape that ends with part of its area inside the body (B2G > 0)."""
    for name, pose, share in zip(names, poses, b2g_percent):
        if share > 0:
            warnings.warn(f"{name} [{pose}]: {share:.2g} % of its area ends inside the body (B2G), cloth caught where "
                          "two parts of the posed body press together (an arm against the torso, the thighs), which "
                          "a static drape cannot free: a pose with the limbs apart avoids it (docs/sequences.md)",
                          DrapeWarning, stacklevel=4)


def drape_results(jobs, body_of: list[int], inp: DrapeInput, x: Tensor, state: BodyState, convergence: list[dict],
                  warm, bound: DistanceBound | None, *, dtype: torch.dtype) -> list[DrapeResult]:
    """One `DrapeResult` per job of a batch draped to x (timings filled in by the caller).

    jobs: the `Draper`'s jobs (template, pose, material); body_of: each job's body in `state`;
    warm: per job its previous frame or None (None: every job skinned); bound: the model's last
    `DistanceBound`, or None; dtype: the results' float type for the body's vertices."""
    batch, cloth, bodies = inp.garments, inp.cloth, inp.bodies
    inside = faces_inside(x, batch, bodies, inp.body_index, bound=bound)
    found = drape_metrics(x, batch, bodies, inp.body_index, cloth=cloth, inside_faces=inside, bound=bound)
    metrics, residual = found.as_dict(), batch.split(found.vertex_residual[:, None])
    inside = torch.split(inside, [int(n) for n in torch.bincount(batch.face_garment, minlength=len(jobs))])
    inits, body_faces = batch.split(inp.x_init), state.faces.cpu().numpy().astype(np.int64)
    xs = [v.cpu().numpy() for v in batch.split(x)]
    crossings = crossings_warned([j.template.name for j in jobs], xs, [j.template.faces for j in jobs])
    inside_warned([j.template.name for j in jobs], [j.pose.label for j in jobs], metrics["b2g_percent"])
    return [DrapeResult(
        name=job.template.name,
        verts=xs[k],
        faces=job.template.faces,
        body_verts=state.verts[body_of[k]].to(dtype).cpu().numpy(),
        body_faces=body_faces,
        x_init=inits[k].cpu().numpy(),
        material=job.material,
        pose=job.pose.label,
        metrics={**{name: float(values[k]) for name, values in metrics.items()}, "piece_crossings": crossings[k]},
        timings={},
        vertex_residual=residual[k][:, 0].cpu().numpy(),
        inside_faces=inside[k].cpu().numpy().astype(bool),
        convergence=convergence[k],
        init="warm" if warm is not None and warm[k] is not None else "skinning",
    ) for k, job in enumerate(jobs)]

"""Fitting a garment authored for another body onto the canonical body (`physdrape fit`)."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import torch

from physdrape.api.placement import check_extent, check_scale, unit_scale
from physdrape.api.types import DrapeError, FitResult
from physdrape.physics.layers import LayerOrder
from physdrape.progress import iteration_progress

#: Height of a top's collar (its highest point) above the canonical body's ``neck01`` joint [m]
#: (the bundled T-shirt's; the generated tops share its neckline construction).
COLLAR_ABOVE_NECK = 0.021
#: Weight [m] of the share of garment vertices inside the body in the alignment's score (1 % inside
#: costs as much as 1 mm more median distance): a loose top is not pulled into the body.
INSIDE_WEIGHT = 0.1


def _align_to_body(verts: np.ndarray, body, *, scale: float = 1.0) -> np.ndarray:
    """Translation t (x → scale·x + t) putting a garment on the canonical body.

    Start: the garment's highest point `COLLAR_ABOVE_NECK` above the ``neck01`` joint (a top
    hangs from the shoulders), centred in x/z on the body within the garment's height band.
    Then a coordinate descent over y and z (2 cm steps, halved four times; x stays centred on the
    left–right symmetric body) minimises the median unsigned distance of sampled garment vertices
    to the body plus `INSIDE_WEIGHT` × the share of them inside it. A garment authored on a human
    body follows its surface (shoulders, chest, hips, legs): on the MakeHuman suits, tight ones
    with a third of their vertices inside the skin included (they are pushed out afterwards), the
    score is smallest within a few millimetres of where their binding puts them, and the inside
    term keeps a loose top where it hangs. The scale is not searched: a smaller garment always
    hugs the body closer.
    """
    from physdrape.geometry.proximity import BodySurface

    shape = body.default_shape(1, dtype=torch.float64)
    canonical = body.rest_verts(shape)[0]
    neck_y = float(body.rest_joints(shape)[0, body.joint_index("neck01"), 1])
    surface = BodySurface(canonical, body.faces)
    bv = canonical.numpy()
    rng = np.random.default_rng(0)
    sample = verts[rng.choice(len(verts), size=min(len(verts), 1000), replace=False)] * scale
    top = float((verts[:, 1] * scale).max())
    y_shift = neck_y + COLLAR_ABOVE_NECK - top
    ys = sample[:, 1] + y_shift
    # torso only: the central 40 % of the garment's width (arms and hands would bias the centre)
    g_mid_x = 0.5 * (sample[:, 0].min() + sample[:, 0].max())
    half = 0.2 * (sample[:, 0].max() - sample[:, 0].min())
    g_core = sample[np.abs(sample[:, 0] - g_mid_x) < half]
    b_band = bv[(bv[:, 1] >= ys.min()) & (bv[:, 1] <= ys.max())]
    b_mid_x = 0.5 * (b_band[:, 0].min() + b_band[:, 0].max())
    b_core = b_band[np.abs(b_band[:, 0] - b_mid_x) < half]
    t = np.array([b_mid_x - g_mid_x, y_shift,
                  0.5 * (b_core[:, 2].min() + b_core[:, 2].max()) - 0.5 * (g_core[:, 2].min() + g_core[:, 2].max())])

    def score(shift: np.ndarray) -> float:
        d = surface.query(torch.from_numpy(sample + shift)).signed_distance.numpy()
        return float(np.median(np.abs(d))) + INSIDE_WEIGHT * float((d < 0).mean())

    value, step = score(t), 0.02
    for _ in range(5):
        moved = True
        while moved:
            moved = False
            for k in (1, 2):
                for sign in (-1.0, 1.0):
                    trial = t.copy()
                    trial[k] += sign * step
                    v = score(trial)
                    if v < value:
                        value, t, moved = v, trial, True
        step /= 2
    return t


def _relax_layered(rest: np.ndarray, faces: np.ndarray, name: str, surface, *, iters: int,
                   time_budget_s: float):
    """Relax the garment on the canonical body (`physics.relax`, `rest` as rest state) with the
    drape's layer order (`garments.layering`, the body normal at each inner vertex, the gap each
    pair has on `rest`) keeping its outer pieces outside the inner ones.

    Returns:
        (positions [m] (V, 3), the relaxation's stats).
    """
    from physdrape.garments.layering import layer_pairs
    from physdrape.garments.pieces import garment_parts
    from physdrape.geometry.garment import Garment
    from physdrape.physics import Cloth, relax

    cloth = Cloth.build(Garment.from_mesh(rest, faces, name=name, dtype=torch.float64))
    body_verts, body_faces = surface.verts[0].numpy(), surface.faces.numpy()
    pairs, separation, _, _ = layer_pairs(rest, garment_parts(rest, faces).piece, body_verts, body_faces)
    if len(pairs):
        index = torch.from_numpy(pairs)
        with torch.no_grad():
            normal = surface.query(torch.from_numpy(rest)[index[:, 1]]).normal
        cloth = replace(cloth, layers=LayerOrder.build(index, normal.to(torch.float64),
                                                       separation=torch.from_numpy(separation)))
    result = relax(torch.from_numpy(rest), cloth, surface, max_iters=iters, time_budget_s=time_budget_s,
                   callback=iteration_progress("fit: relaxing on the body"))
    stats = {"iterations": len(result.history) - 1, "reason": result.reason, "wall_time_s": result.wall_time,
             "residual": float(result.residual[0]), "layer_pairs": len(pairs),
             "energy_J": {k: float(v[0]) for k, v in result.energy_terms.items()}}
    return result.x.numpy(), stats


def fit_garment(path: str | Path, *, align: bool = True, scale: float = 1.0, iters: int = 20,
                time_budget_s: float = 60.0, units: str = "m", body=None) -> FitResult:
    """Place a garment authored for another body onto the canonical Anny body.

    An .mhclo is refit through its MakeHuman binding (exact; `units` does not apply); an .obj/.ply (y-up, in `units`:
    "m", "dm", "cm" or "mm", converted to metres) is scaled by `scale` (a factor near 1 for a
    garment made for a larger or smaller body, not a unit conversion) and translated onto the body (`_align_to_body`), pushed out of the body, then
    relaxed with the physics oracle (`_relax_layered`: the garment's own aligned shape as rest
    state, gravity, body contact and the layer order of its pieces, at most `iters` Newton
    iterations) and validated as a
    template (`garments.validate_garment`: no self-intersections, >= 2 mm body clearance).
    Crossing layers (a suit's top over its trousers) and creases are untangled locally
    (`garments.untangle.untangle_garment`) before the relaxation and again after it, which also
    puts the sheet back at the margin; if the relaxed shape cannot be untangled (the physics has
    no self-collision) the untangled rest shape is returned (``relax["discarded"]`` says so).
    ``relax`` also holds the untangling stats and, for an .mhclo, the displacement from the raw
    MakeHuman refit.

    Raises:
        DrapeError / MeshError: unreadable file, wrong unit, or a malformed mesh.
    """
    from physdrape.garments import load_mhclo, validate_garment
    from physdrape.garments.mhclo import resolve_body_penetration
    from physdrape.garments.untangle import untangle_garment
    from physdrape.geometry.mesh import check_mesh, read_mesh
    from physdrape.geometry.proximity import BodySurface

    path = Path(path).expanduser()
    if not path.is_file():
        raise DrapeError(f"garment file not found: {path} (no such file; give an .obj/.ply in metres, or a "
                         "MakeHuman .mhclo)")
    if path.suffix.lower() not in (".obj", ".ply", ".mhclo"):
        raise DrapeError(f"{path.name}: unsupported extension {path.suffix!r}; use .obj, .ply or .mhclo")
    if body is None:
        from physdrape.body.anny_body import get_anny_body

        body = get_anny_body()
    canonical = body.canonical_verts(dtype=torch.float64)
    faces_b = body.faces
    unit_scale(units)
    check_scale(scale)
    shift = np.zeros(3)
    bv, bf = canonical.numpy(), faces_b.numpy()
    raw = None
    if path.suffix.lower() == ".mhclo":
        g = load_mhclo(path, resolve_margin=None)
        raw = np.asarray(g.verts, np.float64)
        verts, faces, name = raw.copy(), np.asarray(g.faces, np.int64), g.name
        verts, _ = resolve_body_penetration(verts, faces, bv, bf, margin=2e-3)
    else:
        verts, faces = read_mesh(path)
        verts = verts * unit_scale(units)
        name = path.stem
        check_extent(path.name, verts[np.unique(faces)] if faces.min() >= 0 and faces.max() < len(verts) else verts,
                     units)
        check_mesh(verts, faces, name=path.name)
        pre = validate_garment(verts, faces, name=path.name, body=False, check_self_intersections=False,
                               require_clearance=False)
        topo = [e for e in pre.errors if "non-manifold" in e or "more than two faces" in e]
        if topo:
            raise DrapeError(f"{path.name}: {topo[0]}; repair the mesh (e.g. split non-manifold edges) and retry")
        faces = faces.astype(np.int64)
        if align:
            shift = _align_to_body(verts, body, scale=scale)
        verts = verts * scale + shift
        verts, _ = resolve_body_penetration(verts, faces, bv, bf, margin=2e-3)
    # Layered pieces (a suit's top over its trousers) and tight creases cross each other once
    # refit/pushed out: untangle them locally before the physics takes this shape as its rest state.
    verts, info = untangle_garment(verts, faces, bv, bf, margin=2e-3)
    untangle_stats = {"before_relax": info.as_dict()}
    rest = verts
    stats: dict[str, Any] = {"iterations": 0}
    if iters > 0:
        verts, stats = _relax_layered(verts, faces, name, BodySurface(canonical, faces_b), iters=iters,
                                      time_budget_s=time_budget_s)
    if iters > 0:  # the relaxed sheet rests in contact: back out to the margin, untangle again
        relaxed, info = untangle_garment(verts, faces, bv, bf, margin=2e-3)
        untangle_stats["after_relax"] = info.as_dict()
        if info.faces_after and not untangle_stats["before_relax"]["self_intersecting_faces_after"]:
            # the physics has no self-collision: layers it pushed through each other that the
            # local untangling cannot separate again -> keep the valid unrelaxed shape
            stats["discarded"] = (f"the relaxed shape kept {info.faces_after} self-intersecting faces; "
                                  "the aligned, untangled shape (the physics rest state) is returned")
            verts = rest
        else:
            verts = relaxed
    stats["untangle"] = untangle_stats
    if raw is not None:  # how far the fit moved the MakeHuman refit [m]
        disp = np.linalg.norm(verts - raw, axis=1)
        stats["displacement_from_refit_m"] = {"max": float(disp.max()), "mean": float(disp.mean())}
    report = validate_garment(verts, faces, name=name, body=(bv, bf), margin=2e-3, require_clearance=True)
    return FitResult(name=name, verts=verts, faces=faces, scale=float(scale), translation=[float(v) for v in shift],
                     relax=stats, validation=str(report), ok=report.ok, units=units)

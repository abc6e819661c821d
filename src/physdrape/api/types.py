"""The API's data types: its error, the motion spec, and the results of a drape and of a fit."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from physdrape.physics.material import Material


class DrapeError(ValueError):
    """Bad input to the draping API; the message says what was wrong and how to fix it."""


class DrapeWarning(UserWarning):
    """Input the API drapes as asked although it is likely wrong (e.g. ``allow_detached=True``)."""


@dataclass(frozen=True)
class Motion:
    """Frames of a motion used as poses.

    path: a ``.bvh`` file (CMU skeleton), retargeted onto Anny's ``cmu_mb`` rig; or an AMASS-style
        ``.npz`` (``poses`` (N, 3J) axis-angles [rad], optional ``betas``; read by
        `physdrape.body.poses.load_amass_npz`, z-up turned y-up, ``trans`` ignored) on an SMPL
        Draper (``Draper(smpl_model=...)``); its ``betas`` are the shape unless ``drape(shape=...)``
        gives one.
    frames: one frame index, or a (start, stop) half-open range.
    warm_start: for several frames, drape them in order, each starting from the previous frame's
        drape carried along by the body (see `physdrape.api.sequences`). Frame `start` is draped
        cold (the full model from its own skinned X_init); what runs on a later frame:

        - ``"solver"`` (= True, the default): the solver steps and the collision handler only (no
          network pass, f̂ = 0): the previous drape, carried along, keeps relaxing under the
          physics.
        - ``"model"``: the full model (network pass + solver + handler) on the carried X_init. The
          network is trained on skinned X_init and adds its correction again at every frame, so
          the drape drifts over the frames.

        False: every frame from its own skinned X_init, all in one batch (PhysDrape is static: no
        velocities, no history).
    clear_arms: turn each arm of a frame out at the shoulder by the smallest angle that puts it,
        from 10 cm below the shoulder on, 2 cm off the rest of the body (`body.arm_clearance`, as
        DrapeNet and SNUG do): an arm hanging against the torso, as motion capture is full of,
        catches the cloth between them, which a static drape cannot free. An arm clear already
        keeps its pose; each result says by how much its arms were turned
        (`DrapeResult.arms_turned_out_deg`). False: the frames as recorded (a frame whose arms
        pass through the torso is refused, see `Draper`).
    """

    path: str | Path
    frames: int | tuple[int, int] = 0
    warm_start: bool | str = True
    clear_arms: bool = True

    def __post_init__(self) -> None:
        if self.warm_start not in (True, False, "solver", "model"):
            raise DrapeError(f"Motion warm_start must be True/'solver', 'model' or False, got {self.warm_start!r}")
        if not isinstance(self.clear_arms, bool):
            raise DrapeError(f"Motion clear_arms must be True (turn arms off the torso) or False (the frames as "
                             f"recorded), got {self.clear_arms!r}")


@dataclass
class DrapeResult:
    """One draped garment.

    Attributes:
        name: garment label.
        verts: draped garment positions X* [m], shape (V, 3) float (the Draper's dtype).
        faces: garment triangles, shape (F, 3) int64.
        body_verts: posed body [m], shape (Vb, 3); body_faces: (Fb, 3) int64.
        x_init: kinematic initialisation X_init [m], shape (V, 3).
        material: the fabric draped; pose: a label of the body pose.
        metrics: E_strain, E_bend [J, default material], B2G [%], close [%], residual force [N]
            and relative residual [per vertex weight] (see `physdrape.physics.metrics`), and the
            face pairs of two different pieces that intersect ("piece_crossings"; 0 for one piece).
        timings: wall seconds of the batch this garment was draped in (of its thread's group
            where a batch was split between threads), per phase, and ``batch_size``;
            ``per_garment_s`` = total / batch size.
        vertex_residual: ‖F_int‖ / (m_i g) per vertex at X* (V,) (free-hanging parts near 0).
        inside_faces: faces whose centroid is inside the body, (F,) bool (the B2G faces).
        convergence: per solver step t = 0..T: {"energy": E_strain+E_bend+E_grav [J],
            "force": Σ_i ‖F_int,i + f̂_i‖ [N]}; empty unless drape(keep_trace=True).
        init: how X_init was made: "skinning" (the garment skinned onto this body) or "warm"
            (the previous frame's drape carried along by the body's motion, see `Motion`).
        arms_turned_out_deg: how far (left, right) [deg] the arms of a motion's frame were turned
            out at the shoulders to clear the torso (`Motion.clear_arms`); None: the pose as given.
    """

    name: str
    verts: np.ndarray
    faces: np.ndarray
    body_verts: np.ndarray
    body_faces: np.ndarray
    x_init: np.ndarray
    material: Material
    pose: str
    metrics: dict[str, float]
    timings: dict[str, float]
    vertex_residual: np.ndarray
    inside_faces: np.ndarray
    convergence: dict[str, list[float]] = field(default_factory=dict)
    init: str = "skinning"
    arms_turned_out_deg: tuple[float, float] | None = None

    def to_trimesh(self, *, with_body: bool = False):
        """The garment as a `trimesh.Trimesh` (process=False keeps the topology); with_body: a Scene."""
        from physdrape.export import to_trimesh

        return to_trimesh(self, with_body=with_body)

    def save(self, directory: str | Path, formats: Sequence[str] = ("obj", "ply", "glb"), *,
             stem: str = "garment", overwrite: bool = False) -> list[Path]:
        """Write garment and body (``{stem}.obj/.ply``, ``body.obj/.ply``; ``drape.glb`` = one scene with both)
        into `directory`, each file atomically; refuses to overwrite unless `overwrite`."""
        from physdrape.export import save_result

        return save_result(self, directory, formats, stem=stem, overwrite=overwrite)

    def render(self, path: str | Path, *, mode: str = "shaded", size: int = 640) -> Path:
        """Write a PNG of body + garment; mode "shaded" or "residual" (force heatmap, B2G in red)."""
        from physdrape.render import render_result

        return render_result(self, path, mode=mode, size=size)

    def report(self) -> dict[str, Any]:
        """A JSON-able summary (metrics, timings, material, sizes)."""
        m = self.material
        return {
            "garment": self.name,
            "pose": self.pose,
            "num_verts": len(self.verts),
            "num_faces": len(self.faces),
            "material": {"mu_Pa": m.mu, "lam_Pa": m.lam, "k_bend_J": m.k_bend, "density_kg_m2": m.density},
            "E_strain_J": self.metrics["strain"],
            "E_bend_J": self.metrics["bend"],
            "B2G_percent": self.metrics["b2g_percent"],
            "close_percent": self.metrics["close_percent"],
            "piece_crossings": int(self.metrics.get("piece_crossings", 0)),
            "residual_force_N": self.metrics["residual_force"],
            "residual_relative": self.metrics["residual_relative"],
            "init": self.init,
            **({} if self.arms_turned_out_deg is None else {"arms_turned_out_deg": list(self.arms_turned_out_deg)}),
            "timings_s": self.timings,
        }


@dataclass
class FitResult:
    """A garment placed on the canonical body: verts [m] (V, 3), faces (F, 3), the alignment
    (uniform scale, translation [m]), relaxation stats, the validation report (text, ok), and the
    unit the input file was read in (the result is in metres)."""

    name: str
    verts: np.ndarray
    faces: np.ndarray
    scale: float
    translation: list[float]
    relax: dict[str, Any]
    validation: str
    ok: bool
    units: str = "m"

    def report(self) -> dict[str, Any]:
        return {"garment": self.name, "num_verts": len(self.verts), "num_faces": len(self.faces),
                "units": self.units, "scale": self.scale, "translation_m": self.translation, "relax": self.relax,
                "valid": self.ok, "validation": self.validation}

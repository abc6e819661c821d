"""The `Draper`: loads a PhysDrape model once and drapes batches of garments on posed bodies.

A call to `Draper.drape` resolves its specs (`physdrape.api.specs`), broadcasts garments × poses ×
materials into jobs, drapes the independent jobs in batches through the drape pipeline
(`physdrape.pipeline`) and the model, then the frames of warm-started motions one by one
(`physdrape.api.sequences`), and packs one `DrapeResult` per job.

The model, its solver and handler, the body queries, the posed bodies (and their arm check), X_init
and the pipeline's output live on the Draper's device ("cpu" or a CUDA GPU); motions' warm starts
and the oracle's refinement run on the CPU, and results are numpy arrays whatever the device.
"""

from __future__ import annotations

import threading
import time
import warnings
from collections import OrderedDict
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch import Tensor

from physdrape import checkpoint as ckpt
from physdrape.api import placement, sequences, specs
from physdrape.api.batch_threads import drape_groups, thread_groups
from physdrape.api.convergence import solver_convergence
from physdrape.api.results import drape_results
from physdrape.api.specs import BodyPose
from physdrape.api.types import DrapeError, DrapeResult, DrapeWarning, Motion
from physdrape.api.wear import Wear, Wearing
from physdrape.body.arm_clearance import clear_arms
from physdrape.body.model import BodyState
from physdrape.body.poses import arm_torso_penetration, checks_arms
from physdrape.devices import DeviceError, resolve_device
from physdrape.geometry.proximity import BodySurface
from physdrape.physics import Cloth, relax
from physdrape.pipeline import DEFAULT_DTYPE, POSE_DTYPE, TEMPLATES_KEPT, DrapePipeline, PosedBodies, Template, select
from physdrape.progress import iteration_progress, progress_bar
from physdrape.tensor_memo import KeyedMemo

#: Posed body batches a `Draper` keeps, with their surfaces, for drapes on the same shape and poses.
POSED_CACHE_SIZE = 8


@dataclass(frozen=True)
class _Job:
    """One drape of a call: a template on a pose (`pose_id` numbers the call's distinct poses) in
    a material."""

    template: Template
    pose: BodyPose
    pose_id: int
    material: Any


@dataclass(frozen=True)
class _Warm:
    """The previous frame of a warm-started job: its drape X*(t−1) (V, 3) and blended transforms T(t−1)."""

    x: Tensor
    transforms: Tensor


class Draper:
    """Loads a PhysDrape model once and drapes batches of garments.

    Args:
        checkpoint: a checkpoint directory (model.safetensors + config.json) or a run directory
            (its ``latest``); None = the bundled model (`physdrape.checkpoint.bundled_model`).
        steps: solver steps T at inference (paper: 15).
        follow_planes: the solver's body planes followed between body searches (each found again
            once its sample moved `ModelConfig.follow_min_move`), or held between them as in
            training (`PhysDrape.set_eval_planes`); None: the checkpoint's (`eval_follow_planes`).
        passes: network passes before the solver, each reading its inputs at the garment the passes
            before it moved (`ModelConfig.passes`; each costs a pass and its inputs); None: the checkpoint's.
        body: an `AnnyBody` (default: ``get_anny_body()``; loaded on first use), or an
            `SMPLBody` (``physdrape.body.smpl_body``): then every drape is on that SMPL body.
        smpl_model: path of an SMPL / SMPL+H / SMPL-X model file (.npz, or a legacy .pkl read by
            a restricted unpickler) or of a folder holding ``SMPL_{GENDER}.npz|pkl``: shorthand for
            ``body=SMPLBody(smpl_model, gender=smpl_gender)``. The model files are not shipped
            (https://smpl.is.tue.mpg.de). With an SMPL body: shape = β (`betas`), pose = θ
            (axis-angles per SMPL joint) or AMASS frames (`Motion` of an .npz), and garments must be
            .obj/.ply files authored on SMPL's canonical body (β = 0, zero pose).
        smpl_gender: picks the file when `smpl_model` is a folder.
        dtype: dtype of garments, bodies and the solver (the network keeps its own).
        device: where the model, solver, collision handler and body queries run: "cpu" (the
            default), "cuda" (the current GPU) or "cuda:N" (a DrapeError says how to fix a CUDA
            request this machine cannot meet).
        check_pose: refuse (DrapeError) a pose whose arms pass through the torso
            (`body.poses.arm_torso_penetration`), instead of draping it silently.
        arm_contact_tolerance: arm vertices (of those the check samples, every 4th) allowed
            inside the body before a pose is refused: a hand resting on a hip is contact, an arm
            swung into the chest is not.
        compile_network: run the network compiled by `torch.compile`
            (`EncodeProcessDecode.compile_network`): the first drape compiles it (seconds to tens
            of seconds), every later one runs it faster; for a Draper that drapes many garments.
    """

    def __init__(self, checkpoint: str | Path | None = None, *, steps: int = 15, body=None, passes: int | None = None,
                 dtype: torch.dtype = DEFAULT_DTYPE, check_pose: bool = True, arm_contact_tolerance: int = 20,
                 smpl_model: str | Path | None = None, smpl_gender: str = "neutral",
                 device: str | torch.device = "cpu", follow_planes: bool | None = None,
                 compile_network: bool = False) -> None:
        if not isinstance(steps, int) or steps < 0:
            raise DrapeError(f"steps must be a non-negative integer, got {steps!r}")
        if dtype not in (torch.float32, torch.float64):
            raise DrapeError(f"dtype must be torch.float32 or torch.float64, got {dtype}")
        try:
            self.device = resolve_device(device)
        except DeviceError as exc:
            raise DrapeError(str(exc)) from None
        path = Path(checkpoint).expanduser() if checkpoint is not None else ckpt.bundled_model()
        if not path.exists():
            hint = "the bundled model is not installed" if checkpoint is None else f"{path} does not exist"
            raise DrapeError(
                f"no PhysDrape model: {hint}. Train one with `physdrape train --recipe configs/recipes/shipped.yaml "
                f"--run-dir runs/shipped`, which writes it to {ckpt.bundled_model()}, or pass an exported model "
                f"directory (model.safetensors + config.json) with --checkpoint (API: Draper(checkpoint=...))")
        try:
            self.model, _ = ckpt.load_model(path, passes=passes)
        except ckpt.CheckpointError as exc:
            raise DrapeError(f"cannot load the PhysDrape model: {exc}") from None
        self.model.to(self.device)
        if follow_planes is not None:
            self.model.set_eval_planes(follow_planes)
        if compile_network:
            self.model.gnn.compile_network()
        self.model_config = self.model.config
        self.checkpoint = path
        self.steps = steps
        self.dtype = dtype
        self.check_pose = check_pose
        self.arm_contact_tolerance = arm_contact_tolerance
        self._bodies: dict[str, Any] = {}
        if body is not None and smpl_model is not None:
            raise DrapeError("give either body=... or smpl_model=..., not both")
        if smpl_model is not None:
            body = specs.load_smpl_body(smpl_model, gender=smpl_gender)
        if body is not None:
            if not hasattr(body, "rig"):
                raise DrapeError(f"body must be an AnnyBody or an SMPLBody, got {type(body).__name__}")
            self._bodies[body.rig] = body
        #: the SMPL body when this Draper drapes on SMPL (then Anny is never loaded), else None
        self.smpl = self._bodies.get("smpl")
        self._wearing = Wearing(by_binding=self.smpl is None)
        self._pipelines: dict[str, DrapePipeline] = {}
        # the garments named by text specs, and whether each hangs on the canonical body: the
        # pipelines' TEMPLATES_KEPT most recently used (a manifest of thousands holds that many)
        self._templates, self._detached = KeyedMemo(TEMPLATES_KEPT), KeyedMemo(TEMPLATES_KEPT)
        self._canonical: dict[str, tuple[np.ndarray, BodySurface]] = {}
        self._named_poses: dict[str, list[BodyPose]] = {}
        #: the last few posed body batches (their surfaces built on first use), by rig, shapes and poses
        self._posed: OrderedDict[tuple, tuple[PosedBodies, Tensor | None]] = OrderedDict()
        self._posed_lock = threading.Lock()  # a batch split between threads poses its groups side by side

    # ------------------------------------------------------------------ inputs
    def body(self, rig: str = "anny"):
        """The Anny body of `rig` ("anny" for presets/random poses, "cmu_mb" for BVH), cached;
        "smpl": the SMPL body given to the Draper."""
        if rig == "smpl" and rig not in self._bodies:
            raise DrapeError("this Draper has no SMPL body: create it with Draper(smpl_model=PATH) "
                             "(CLI: --smpl-model FILE)")
        if rig not in self._bodies:
            from physdrape.body.anny_body import get_anny_body

            self._bodies[rig] = get_anny_body(rig)
        return self._bodies[rig]

    def pipeline(self, rig: str) -> DrapePipeline:
        """The drape pipeline of body rig `rig` (its transfers and garments cached), in the Draper's
        dtype, building on its device."""
        if rig not in self._pipelines:
            self._pipelines[rig] = DrapePipeline(self.body(rig), dtype=self.dtype, device=self.device)
        return self._pipelines[rig]

    def garment(self, spec, *, units: str = "m") -> Template:
        """Resolve a garment spec (see `physdrape.api.specs.garment_template`) whose files and
        meshes are in `units`; text specs are cached."""
        def resolve() -> Template:
            return specs.garment_template(spec, smpl=self.smpl is not None, units=units)

        return self._templates.get((str(spec), units), resolve) if isinstance(spec, (str, Path)) else resolve()

    def detached(self, template: Template, rig: str = "anny") -> str | None:
        """Why `template` cannot hang on the canonical body of `rig` (it neither touches nor
        surrounds it, see `physdrape.api.placement`), or None; computed once per template."""
        def reason() -> str | None:
            if rig not in self._canonical:
                body = self.body(rig)
                verts = body.canonical_verts(dtype=torch.float64)
                self._canonical[rig] = (verts.numpy(), BodySurface(verts, body.faces))
            body_verts, surface = self._canonical[rig]
            nearest, gap = placement.attachment(template.verts, body_verts, surface)
            return placement.detached_reason(template.name, nearest, gap)

        return self._detached.get((template.key, rig), reason)

    def _check_attached(self, jobs: list[_Job], allow_detached: bool) -> None:
        """Refuse (or, allow_detached, warn about) templates that hang on nothing."""
        reasons = dict.fromkeys(r for job in jobs if (r := self.detached(job.template, job.pose.rig)))
        if not reasons:
            return
        if not allow_detached:
            canonical = ("SMPL with β = 0 in its zero pose, the T-pose" if self.smpl is not None
                         else "Anny with all phenotypes 0.5 in its rest A-pose")
            raise DrapeError(f"{'; '.join(reasons)}. "
                             f"{placement.detached_advice(canonical, fit_hint=self.smpl is None)}")
        for reason in reasons:
            warnings.warn(f"{reason}; draped anyway, as allowed", DrapeWarning, stacklevel=3)

    def shape(self, spec=None) -> Tensor:
        """Phenotypes (1, 6) float64 from None (canonical), a {name: value} dict or an array of 6;
        on an SMPL Draper: β (see `betas`)."""
        if self.smpl is not None:
            return self.betas(spec)
        return specs.anny_shape(spec, self.body("anny"))

    def betas(self, spec=None) -> Tensor:
        """SMPL shape β (1, num_betas) float64 (see `physdrape.api.specs.smpl_betas`)."""
        return specs.smpl_betas(spec, self.body("smpl"))

    def poses(self, spec=None) -> list[BodyPose]:
        """Poses from None (the default preset), a preset name, "random:SEED", an array (J, 3) or
        (N, J, 3) axis-angle [rad] on the "anny" rig, or a `Motion` (BVH frames). On an SMPL
        Draper: None / "rest" (zero θ, the T-pose), θ as (J, 3), (3J,), (N, J, 3) or (N, 3J)
        axis-angles [rad], or a `Motion` of an AMASS .npz."""
        if isinstance(spec, Motion):
            return sequences.tag_frames(spec, specs.motion_poses(spec, self.body, smpl=self.smpl is not None))
        if self.smpl is not None:
            return specs.smpl_poses(spec, self.body("smpl"))
        spec = specs.DEFAULT_POSE if spec is None else spec
        if isinstance(spec, str):  # a preset or a seeded draw (the sampler poses and checks bodies): once
            if spec not in self._named_poses:
                self._named_poses[spec] = specs.anny_poses(spec, self.body)
            return list(self._named_poses[spec])
        return specs.anny_poses(spec, self.body)

    material = staticmethod(specs.material)

    def transfer(self, template: Template, rig: str):
        """The garment's `SkinningTransfer` onto `rig` (fitted on first use, kept for the pipeline's
        `TEMPLATES_KEPT` most recently used garments)."""
        return self.pipeline(rig).transfer(template)

    # ------------------------------------------------------------------ draping
    def drape(self, garments, *, shape=None, pose=None, material=None, refine: bool = False,
              steps: int | None = None, keep_trace: bool = False, batch_size: int = 8, progress: bool = False,
              refine_iters: int = 30, refine_time_s: float = 60.0, units: str = "m",
              allow_detached: bool = False, sizing: str | None = None,
              grip: float | None = None, closures=None, layers: str | None = None) -> list[DrapeResult]:
        """Drape garments onto a shaped, posed Anny body (or the Draper's SMPL body).

        Args:
            garments: one garment spec or a list (see `garment`).
            shape: phenotypes: None (canonical, all 0.5), a dict ({"weight": 0.8}; missing at 0.5),
                or 6 values in [0, 1] in the order `PHENOTYPE_NAMES`. SMPL: β, up to num_betas
                values (padded with zeros); None = β = 0, or the betas of AMASS frames.
            pose: one pose spec (see `poses`) or a list; a spec may expand to several frames.
                A multi-frame `Motion` with warm_start (the default) is draped frame by frame,
                each frame from the previous frame's drape (see `Motion`); its first frame, and
                every other job, from the skinned X_init in batches.
            material: a preset name or `Material`, or a list (one per job).
            steps: solver steps T for this call (default: the Draper's `steps`).
            refine: polish each drape with the physics oracle (`physics.relax`, projected Newton,
                penalty contact; at most `refine_iters` iterations / `refine_time_s` seconds per batch).
            keep_trace: record the solver's energy and force per step (`DrapeResult.convergence`).
            batch_size: garments per model call (on the CPU with several torch threads, a batch on
                several poses drapes as groups side by side, one per thread: `api.batch_threads`);
                progress: show a tqdm bar over the garments.
            units: the unit of garment files (.obj/.ply) and (verts, faces) given here: "m" (the
                default), "dm", "cm" or "mm"; they are converted to metres (the bundled and
                generated garments and .mhclo are placed in metres already). Results are in metres.
            allow_detached: drape a garment that neither touches nor surrounds the canonical body
                (warning with a `DrapeWarning`) instead of refusing it with a DrapeError.
            sizing: the garments' rest shape on the body (`garments.sizing`): "fit" follows the
                body's shape (an .mhclo through its MakeHuman binding, any other garment through
                the skinning transfer's shape part), so a garment is worn where it was authored;
                "fixed" keeps the template's (try-on: one size on every body). None: "fit" for
                .mhclo garments, "fixed" for the others.
            grip: the grip stiffness κ [N/m³] of the waistband of a garment's lower piece
                (trousers, a skirt, alone or under a top; `physics.grip`: its strip of fabric held
                tangentially where it was put on, as friction and elastic hold a waistband); 0
                turns it off; None: `DEFAULT_GRIP_STIFFNESS`. Tops have no waistband to grip
                (`garments.pieces`).
            closures: what ties a garment's overlapping panels (button and wrap fronts) with
                stitches (`physics.stitches`): "auto" (where the template's panels overlap on the
                canonical body, `garments.closures`), "off", or the stitched vertex pairs of the
                template, (K, 2) indices (an .mhclo template is remeshed: its own indices); None:
                "auto".
            layers: "auto" (None): a multi-piece garment's pieces keep the order they have where
                they overlap on the canonical body, the outer outside the inner (`physics.layers`);
                "off".

        Jobs are the broadcast of garments × poses × materials (each list of length 1 or N).

        Returns:
            one `DrapeResult` per job, in order.
        """
        g_specs = garments if isinstance(garments, list) else [garments]
        p_specs = pose if isinstance(pose, list) else [pose]
        m_specs = material if isinstance(material, list) else [material]
        if not g_specs:
            raise DrapeError("no garments given")
        if batch_size < 1:
            raise DrapeError(f"batch_size must be ≥ 1, got {batch_size}")
        if steps is not None and (not isinstance(steps, int) or steps < 0):
            raise DrapeError(f"steps must be a non-negative integer, got {steps!r}")
        steps = self.steps if steps is None else steps
        templates = [self.garment(g, units=units) for g in g_specs]
        wear = Wear.check(sizing=sizing, grip=grip, closures=closures, layers=layers, templates=templates)
        body_poses = [bp for p in p_specs for bp in self.poses(p)]
        if shape is not None:  # an explicit shape overrides the betas stored in AMASS frames
            body_poses = [replace(bp, shape=None) for bp in body_poses]
        materials = [self.material(m) for m in m_specs]
        shape_t = self.shape(shape)
        if len({len(templates), len(body_poses), len(materials)} - {1}) > 1:
            raise DrapeError(f"cannot broadcast {len(templates)} garments, {len(body_poses)} poses and "
                             f"{len(materials)} materials: give lists of length 1 or of one common length")
        n = max(len(templates), len(body_poses), len(materials))
        jobs = [_Job(templates[i % len(templates)], body_poses[i % len(body_poses)], i % len(body_poses),
                     materials[i % len(materials)]) for i in range(n)]
        self._check_attached(jobs, allow_detached)
        prev = sequences.predecessors([j.pose for j in jobs], [j.template.key for j in jobs])
        options = {"steps": steps, "refine": refine, "keep_trace": keep_trace, "refine_iters": refine_iters,
                   "refine_time_s": refine_time_s, "wear": wear}
        results: dict[int, DrapeResult] = {}
        carried: dict[int, _Warm] = {}  # the last drape of each running sequence
        bar = None
        if progress:
            bar = progress_bar(total=n, unit="garment", desc="draping")
        try:
            cold = [i for i in range(n) if prev[i] is None]
            for c in range(0, len(cold), batch_size):
                chunk = cold[c:c + batch_size]
                for rig in dict.fromkeys(jobs[i].pose.rig for i in chunk):  # one rig (topology) per model call
                    part = [i for i in chunk if jobs[i].pose.rig == rig]
                    res, warm = self._drape_part([jobs[i] for i in part], shape_t, **options)
                    results.update(zip(part, res))
                    carried.update((i, w) for i, w in zip(part, warm) if w is not None)
                    if bar is not None:
                        bar.update(len(part))
            for i in range(n):
                if prev[i] is None:
                    continue
                [res], [warm] = self._drape_batch([jobs[i]], shape_t, warm=[carried.pop(prev[i])],
                                                  physics_only=jobs[i].pose.sequence[2] == "solver", **options)
                results[i], carried[i] = res, warm
                if bar is not None:
                    bar.update(1)
        finally:  # also on Ctrl-C: end the bar's line, so that what follows starts on its own
            if bar is not None:
                bar.close()
        return [results[i] for i in range(n)]

    def _posed_bodies(self, rig: str, shapes: Tensor, poses: Tensor, labels: list[str],
                      clear: list[bool] | None = None) -> tuple[PosedBodies, Tensor | None]:
        """The bodies of `rig` in `shapes` and `poses`, posed and (with `check_pose`) checked for arms
        through the torso once; the last `POSED_CACHE_SIZE` batches are kept with their surfaces.
        clear: per pose, whether to turn its arms out where they press against the torso
        (`body.arm_clearance.clear_arms`); also returns those turns (B, 2) [deg], or None."""
        clear = clear if clear is not None and any(clear) and checks_arms(rig) else None
        key = (rig, self.check_pose, shapes.shape, poses.shape, shapes.cpu().numpy().tobytes(),
               poses.cpu().numpy().tobytes(), None if clear is None else tuple(clear))
        with self._posed_lock:
            if key in self._posed:
                self._posed.move_to_end(key)
                return self._posed[key]
        body = self.body(rig)
        state = body(shapes.to(self.device), poses.to(self.device))  # posed where the drape runs
        turns = None
        if clear is not None:
            turned, turns = clear_arms(body, state, poses.to(self.device), rows=torch.tensor(clear))
            if bool((turns > 0).any()):
                state = body(shapes.to(self.device), turned)
        if self.check_pose and checks_arms(rig):
            self._refuse_penetrating_poses(state, body, labels)
        posed = (PosedBodies(state), turns)
        with self._posed_lock:
            self._posed[key] = posed
            while len(self._posed) > POSED_CACHE_SIZE:
                self._posed.popitem(last=False)
        return posed

    def _refuse_penetrating_poses(self, state: BodyState, body, labels: list[str]) -> None:
        """A static drape cannot resolve cloth pinched between arm and torso: refuse such poses."""
        counts = arm_torso_penetration(state, body, device=self.device).tolist()
        bad = [f"{label} ({count} arm vertices inside the body)" for label, count in zip(labels, counts)
               if count > self.arm_contact_tolerance]
        if bad:
            raise DrapeError(
                f"pose drives the arms through the torso: {'; '.join(bad)}. PhysDrape drapes static poses with "
                "the arms clear of the body: choose another pose or frame (or Draper(check_pose=False) to drape anyway)"
            )

    def _drape_part(self, jobs: list[_Job], shape: Tensor, **options) -> tuple[list[DrapeResult], list[_Warm | None]]:
        """`_drape_batch` of one rig's jobs, on the CPU split by pose between torch's threads and
        into packs of at most `api.batch_threads.CPU_PACK_VERTICES` vertices."""
        groups = thread_groups(jobs, self.device, refine=options["refine"])
        if len(groups) < 2:
            return self._drape_batch(jobs, shape, **options)
        pipeline = self.pipeline(jobs[0].pose.rig)
        for template in {job.template.key: job.template for job in jobs}.values():  # first use outside the threads
            pipeline.transfer(template)
            pipeline.garment(template)
        return drape_groups(lambda part: self._drape_batch(part, shape, **options), jobs, groups)

    @torch.no_grad()
    def _drape_batch(self, jobs: list[_Job], shape: Tensor, *, steps: int, refine: bool, keep_trace: bool,
                     refine_iters: int, refine_time_s: float, wear: Wear,
                     warm: list[_Warm] | None = None,
                     physics_only: bool = False) -> tuple[list[DrapeResult], list[_Warm | None]]:
        """Drape one batch of jobs on one rig. warm: per job the previous frame (None: X_init by
        skinning); physics_only: skip the network (solver steps with f̂ = 0 and the collision
        handler only). Returns the results and, for frames of a warm-started motion, what the
        next frame starts from (else None)."""
        t0 = time.perf_counter()
        rig = jobs[0].pose.rig
        pipeline = self.pipeline(rig)
        poses = {job.pose_id: job.pose for job in jobs}  # one posed body per distinct pose
        slot = {pose_id: k for k, pose_id in enumerate(poses)}
        pose_t = torch.cat([p.pose for p in poses.values()]).to(POSE_DTYPE)
        shapes = torch.cat([shape if p.shape is None else p.shape for p in poses.values()]).to(POSE_DTYPE)
        posed, turns = self._posed_bodies(rig, shapes, pose_t, [p.label for p in poses.values()],
                                          [p.clear_arms for p in poses.values()])
        state = posed.state
        t1 = time.perf_counter()
        pipeline_jobs, following = [], []
        for k, job in enumerate(jobs):
            b = slot[job.pose_id]
            x_init = transforms = None
            if job.pose.sequence is not None or (warm is not None and warm[k] is not None):
                on_cpu = posed.state_on("cpu")  # a motion's warm starts are carried on the CPU
                transforms = sequences.blended_transforms(pipeline.transfer(job.template), select(on_cpu, b))
                if warm is not None and warm[k] is not None:
                    x_init = sequences.carried_init(pipeline.transfer(job.template), warm[k].x, warm[k].transforms,
                                                    transforms, select(on_cpu, b))
            pipeline_jobs.append(self._wearing.job(job.template, b, job.material, x_init, wear, posed,
                                                   shapes[b:b + 1], pipeline))
            following.append(transforms)
        inp = pipeline.build(pipeline_jobs, posed)
        t2 = time.perf_counter()
        run = self.model.physics_only if physics_only else self.model
        out = run(inp, steps=steps, keep_trace=keep_trace)
        x = out.x
        t3 = time.perf_counter()
        convergence = solver_convergence(out, inp, len(jobs)) if keep_trace else [{} for _ in jobs]
        t3b = time.perf_counter()
        if refine:  # the oracle runs on the CPU (scipy's sparse factorisations)
            c64 = Cloth.build(inp.garments.to(torch.float64, device="cpu"), [job.material for job in jobs])
            c64 = c64.with_terms_of(inp.cloth)  # the oracle minimises the same energy (grip, stitches)
            b64 = BodySurface(state.verts.to(device="cpu", dtype=torch.float64), state.faces)
            body_of_garment = torch.tensor([job.body for job in pipeline_jobs], device="cpu")
            res = relax(x.to(device="cpu", dtype=torch.float64), c64, b64, body_of_garment, max_iters=refine_iters,
                        time_budget_s=refine_time_s, contact_stiffness=self.model_config.contact_stiffness,
                        margin=self.model_config.margin, callback=iteration_progress("oracle polish (refine)"))
            x = res.x.to(device=self.device, dtype=self.dtype)
        t4 = time.perf_counter()
        results = drape_results(jobs, [pj.body for pj in pipeline_jobs], inp, x, state, convergence, warm, out.bound,
                                dtype=self.dtype)
        t5 = time.perf_counter()
        timings = {"body_s": t1 - t0, "init_s": t2 - t1, "model_s": t3 - t2, "trace_s": t3b - t3, "refine_s": t4 - t3b,
                   "metrics_s": t5 - t4, "total_s": t5 - t0, "batch_size": float(len(jobs))}
        timings["per_garment_s"] = timings["total_s"] / len(jobs)
        for r, job in zip(results, jobs):
            r.timings = dict(timings)
            if turns is not None and bool((turns[slot[job.pose_id]] > 0).any()):
                r.arms_turned_out_deg = tuple(float(a) for a in turns[slot[job.pose_id]])
        xs = inp.garments.split(x)
        nxt = [None if t is None else _Warm(xs[k].to(device=t.device, dtype=POSE_DTYPE), t)
               for k, t in enumerate(following)]
        return results, nxt


_DEFAULT_DRAPER: Draper | None = None


def drape(garments="default", **kwargs) -> list[DrapeResult]:
    """`Draper().drape(...)` with a Draper (the bundled model) created on first use and reused."""
    global _DEFAULT_DRAPER
    if _DEFAULT_DRAPER is None:
        _DEFAULT_DRAPER = Draper()
    return _DEFAULT_DRAPER.drape(garments, **kwargs)

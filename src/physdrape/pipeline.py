"""The drape pipeline: garment templates × posed bodies × materials → the model's input.

Every drape takes this path, whoever asks for it: the public API (`physdrape.api.Draper`), the
training data (`physdrape.train.data.DrapeSource`) and the evaluation protocol
(`physdrape.eval.evaluate`). Per job it takes a template authored on the body model's canonical
body, one posed body of a `BodyState` batch and a material, and builds the kinematic
initialisation X_init (the garment skinned onto the posed body by its `SkinningTransfer`, then
edge-stretch limited with the body held out; paper Eq. 5) unless the job brings its own start (a
warm-started frame of a sequence). What does not change between drapes is computed once and
cached per template: its skinning transfer onto the body model and its rest-state `Garment`.

Devices: bodies come posed in `POSE_DTYPE` wherever their caller posed them (the API poses them on
its device); garments are skinned and their stretch limited (X_init, still in `POSE_DTYPE`) on the
pipeline's device, against the posed bodies' surfaces there, the model's own, and the
`DrapeInput` handed to the model (garments, cloth, X_init, body surfaces) is built there, the
templates' rest states and transfers cached there. On a GPU a new pose then costs no body surface
on the CPU. A `PosedBodies` holds the
body surfaces (Warp BVHs) of one posed batch, built on first use: a caller that drapes on the
same bodies again (the API, for a shape and pose it has seen) hands the same `PosedBodies` back
and builds no surface twice.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, fields, replace

import numpy as np
import torch
from torch import Tensor

from physdrape.body.model import BodyState
from physdrape.body.skinning_transfer import LIMIT_FIELDS, BodySearch, SkinningTransfer
from physdrape.garments import layering
from physdrape.garments.closures import panel_overlaps
from physdrape.garments.pieces import GarmentParts, garment_parts, waistband_band
from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.intersections import piece_crossings
from physdrape.geometry.proximity import BodySurface
from physdrape.model import DrapeInput
from physdrape.physics import Cloth, Material
from physdrape.physics.grip import DEFAULT_GRIP_STIFFNESS, Grip
from physdrape.physics.layers import LayerOrder, push_outer_out
from physdrape.physics.stitches import DEFAULT_STITCH_STIFFNESS, Stitches
from physdrape.tensor_memo import KeyedMemo
from physdrape.threads import parallel_map

#: The dtype of the garments, bodies and X_init handed to the model unless a caller asks otherwise
#: (the API's `Draper` and the evaluation share it, so `physdrape eval` measures what users run).
DEFAULT_DTYPE = torch.float32
#: The dtype bodies are posed and garments skinned in before the cast to the model's dtype.
POSE_DTYPE = torch.float64
#: Body-surface points a drape asks about per garment vertex, at the least: X_init's contact
#: (V), the network's input (V), the solver's first planes on the vertices and face centroids
#: (V + F ≈ 3 V), the collision handler's and the metrics' (V + F each). Told to the surfaces
#: (`BodySurface.expect`), so that a new body finds its doubtful faces before the first query.
QUERIES_PER_VERTEX = 11
#: Garment templates whose derived data (skinning transfer, rest-state quantities, pieces, layer
#: pairs, closures) a pipeline keeps, the most recently used: a batch draping more at once derives
#: some again; a dataset of thousands of garments draped in one process holds this many (about
#: 1.5 MB each for a 3k-vertex garment), not every one.
TEMPLATES_KEPT = 64


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.sha1()
    for a in arrays:
        a = np.ascontiguousarray(a)
        h.update(str(a.dtype).encode() + str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


@dataclass(frozen=True, eq=False)
class Template:
    """A garment template on the canonical body.

    Attributes:
        name: a label for messages and outputs.
        verts: rest positions [m], shape (V, 3) float64.
        faces: triangles, shape (F, 3) int64.
        key: a digest of verts and faces: equal meshes share cached transfers.
        sizer: what gives the garment its rest shape on another body when it is sized to fit
            (`garments.sizing.MhcloSizer` for an .mhclo garment), or None.
    """

    name: str
    verts: np.ndarray
    faces: np.ndarray
    key: str
    sizer: object | None = None

    @staticmethod
    def from_mesh(verts, faces, *, name: str = "garment") -> Template:
        """A template from array-likes (numpy or torch) of rest positions [m] (V, 3) and faces (F, 3)."""
        v = np.asarray(verts.detach().cpu() if isinstance(verts, Tensor) else verts, dtype=np.float64)
        f = np.asarray(faces.detach().cpu() if isinstance(faces, Tensor) else faces).astype(np.int64)
        return Template(name=name, verts=v, faces=f, key=_digest(v, f))

    @property
    def num_verts(self) -> int:
        return int(self.verts.shape[0])


class PosedBodies:
    """A posed body batch and its body surfaces, each built once, on first use.

    Args:
        state: the posed bodies (B bodies, in `POSE_DTYPE`, on any device).
    """

    def __init__(self, state: BodyState) -> None:
        self.state = state
        self._surfaces: dict[tuple, BodySurface] = {}
        self._states: dict[torch.device, BodyState] = {}

    def state_on(self, device: torch.device | str) -> BodyState:
        """The posed bodies with their tensors on `device` (copied once)."""
        device = torch.device(device)
        if self.state.verts.device == device:
            return self.state
        if device not in self._states:
            moved = {f.name: getattr(self.state, f.name).to(device) for f in fields(self.state)
                     if isinstance(getattr(self.state, f.name), Tensor)}
            self._states[device] = replace(self.state, **moved)
        return self._states[device]

    def surface(self, dtype: torch.dtype, device: torch.device | str) -> BodySurface:
        """All B bodies as one `BodySurface` in `dtype` on `device` (the model's queries)."""
        device = torch.device(device)
        key = ("all", dtype, device)
        if key not in self._surfaces:
            self._surfaces[key] = BodySurface(self.state.verts.detach().to(device=device, dtype=dtype),
                                              self.state.faces)
        return self._surfaces[key]

    def single(self, index: int, dtype: torch.dtype, device: torch.device | str) -> BodySurface:
        """Body `index` alone as a `BodySurface` on `device` (what the skinning transfer holds the
        garment out of while it limits X_init's stretch), in `dtype`: a selection of the batch's
        surface in `dtype` there (the model's own on that device), its BVH shared."""
        batch = self.surface(dtype, device)
        if self.state.batch_size == 1:
            return batch
        key = ("one", index, dtype, torch.device(device))
        if key not in self._surfaces:
            self._surfaces[key] = batch.select(index)
        return self._surfaces[key]


@dataclass(frozen=True)
class Job:
    """One drape: `template` on body `body` of the posed batch, in `material`; `x_init` [m] (V, 3)
    a start of its own (a warm-started frame) or None for the skinned X_init; `rest` [m] (V, 3)
    the garment's rest shape on this body in its rest pose (a garment sized to fit,
    `garments.sizing`) or None for the template's; `grip` the grip stiffness κ [N/m³] of its
    waistband (`physics.grip`; 0: none); `stitches` (K, 2) template vertex pairs tied by closures
    (`physics.stitches`, rest distance = on the rest shape) or None; `layers` whether its pieces
    keep their layer order (`physics.layers`)."""

    template: Template
    body: int
    material: Material
    x_init: Tensor | None = None
    rest: np.ndarray | None = None
    grip: float = 0.0
    stitches: np.ndarray | None = None
    layers: bool = False


def _rows(batch: GarmentBatch, k: int) -> slice:
    """The rows of garment `k` in the batch's packed vertices."""
    return slice(int(batch.vert_offsets[k]), int(batch.vert_offsets[k + 1]))


def select(state: BodyState, index: int) -> BodyState:
    """Body `index` of a posed batch as a batch of one (what a skinning transfer takes)."""
    sl = slice(index, index + 1)
    return BodyState(verts=state.verts[sl], faces=state.faces, normals=state.normals[sl] if state.normals.numel() else
                     state.normals, rest_verts=state.rest_verts[sl], vertex_transforms=state.vertex_transforms[sl])


class DrapePipeline:
    """Builds `DrapeInput`s for one body model (one rig and topology).

    Args:
        body: the body model the templates are authored on (`canonical_verts`, `faces`), e.g. an
            `AnnyBody` of one rig or an `SMPLBody`.
        dtype: of the garments, bodies and X_init handed to the model.
        device: where the model's input is built (see the module docstring).
        x_init_limits: X_init's strain limiting other than the transfer's defaults: fields of
            `SkinningTransfer` named in `LIMIT_FIELDS` (e.g. ``{"min_stretch": None}``: compressed
            edges left as skinned); None keeps the defaults.
        templates_kept: how many templates' derived data are kept, the most recently used
            (default `TEMPLATES_KEPT`; a training set's source keeps all of its garments').
    """

    def __init__(self, body, *, dtype: torch.dtype = DEFAULT_DTYPE, device: torch.device | str = "cpu",
                 x_init_limits: dict | None = None, templates_kept: int | None = None) -> None:
        unknown = sorted(set(x_init_limits or ()) - set(LIMIT_FIELDS))
        if unknown:
            raise ValueError(f"x_init_limits: unknown field(s) {unknown}; choose among {list(LIMIT_FIELDS)}")
        self.body = body
        self.dtype = dtype
        self.device = torch.device(device)
        self.x_init_limits = dict(x_init_limits or {})
        self._body_search: BodySearch | None = None  # what every template's fit searches on the body
        # what is derived from each template, by its key, for the most recently used
        kept = TEMPLATES_KEPT if templates_kept is None else templates_kept
        (self._transfers, self._device_transfers, self._garments, self._bands, self._closures, self._pieces,
         self._layer_pairs) = (KeyedMemo(kept) for _ in range(7))

    def transfer(self, template: Template) -> SkinningTransfer:
        """The template's skinning transfer onto the body model (fitted on first use, then cached)."""
        def fit() -> SkinningTransfer:
            if self._body_search is None:  # the canonical body, formed and searched once
                self._body_search = BodySearch.of(self.body.canonical_verts(dtype=torch.float64), self.body.faces)
            search = self._body_search
            transfer = SkinningTransfer.fit(torch.from_numpy(search.verts), search.faces,
                                            torch.from_numpy(template.verts), torch.from_numpy(template.faces),
                                            search=search)
            return replace(transfer, **self.x_init_limits)

        return self._transfers.get(template.key, fit)

    def _transfer_here(self, template: Template) -> SkinningTransfer:
        """The template's transfer on the pipeline's device (moved once)."""
        if self.device.type == "cpu":
            return self.transfer(template)
        return self._device_transfers.get(template.key, lambda: self.transfer(template).to(self.device))

    def garment(self, template: Template, rest: np.ndarray | None = None) -> Garment:
        """The template's rest-state quantities in the pipeline's dtype, on its device (computed
        once); with `rest` [m] (V, 3), those of that rest shape (computed each time)."""
        if rest is not None:
            return Garment.from_mesh(rest, template.faces, name=template.name, dtype=self.dtype).to(device=self.device)
        return self._garments.get(template.key, lambda: Garment.from_mesh(
            template.verts, template.faces, name=template.name, dtype=self.dtype).to(device=self.device))

    def x_init(self, template: Template, state: BodyState | PosedBodies, index: int = 0,
               rest: np.ndarray | None = None, limits: dict | None = None) -> Tensor:
        """X_init [m] (V, 3) of `template` on body `index` of `state`, in the state's dtype, on the
        pipeline's device; with `rest` [m] (V, 3), that rest shape skinned instead of the
        template's plus ΔX_shape; with `limits`, fields of `LIMIT_FIELDS` other than the
        pipeline's for this X_init."""
        posed = state if isinstance(state, PosedBodies) else PosedBodies(state)
        transfer = self._transfer_here(template)
        if limits:
            transfer = replace(transfer, **limits)
        with torch.no_grad():
            body = select(posed.state_on(self.device), index)
            rest_t = None if rest is None else torch.as_tensor(rest, dtype=body.rest_verts.dtype, device=self.device)
            return transfer.apply(body, rest_verts=rest_t, surface=posed.single(index, self.dtype, self.device))[0]

    def fitted_rest(self, template: Template, state: BodyState | PosedBodies, index: int = 0) -> np.ndarray:
        """The skinning transfer's shape part X_temp + ΔX_shape [m] (V, 3) float64 on body `index`
        of `state`: the rest shape of a mesh garment sized to fit (`garments.sizing`); computed on
        the pipeline's device."""
        posed = state if isinstance(state, PosedBodies) else PosedBodies(state)
        with torch.no_grad():
            body = select(posed.state_on(self.device), index)
            return self._transfer_here(template).shaped_rest(body)[0].to(torch.float64).cpu().numpy()

    def build(self, jobs: Sequence[Job], state: BodyState | PosedBodies) -> DrapeInput:
        """The model's input for `jobs` on the posed bodies of `state` (one job per garment), on the
        pipeline's device; a `PosedBodies` lends its surfaces (built on first use, then reused)."""
        if not jobs:
            raise ValueError("no jobs to drape")
        device = self.device
        posed = state if isinstance(state, PosedBodies) else PosedBodies(state)
        asked = QUERIES_PER_VERTEX * sum(job.template.num_verts for job in jobs)
        surface = posed.surface(self.dtype, device)  # the model's, and X_init's
        surface.expect(asked)
        surface.forget_recent()  # what a drape reuses is its own: a repeated drape costs what the first did
        skinned = self._x_inits(jobs, posed)
        x_init = [(skinned[i] if job.x_init is None else job.x_init).to(device=device, dtype=self.dtype)
                  for i, job in enumerate(jobs)]
        batch = GarmentBatch.pack([self.garment(job.template, job.rest) for job in jobs])
        cloth = Cloth.build(batch, [job.material for job in jobs])
        bodies = posed.surface(self.dtype, device)
        body_of_job = torch.tensor([job.body for job in jobs], dtype=torch.int64, device=device)
        x_init = torch.cat(x_init)
        layers = self._layers(jobs, batch, x_init, bodies)
        if layers is not None:
            # skinning moves overlapping pieces apart or through each other where the pose bends
            # them differently: X_init starts with its pieces in their layer order
            with torch.no_grad():
                x_init, layers = self._in_layer_order(jobs, posed, batch, x_init, layers, bodies)
            cloth = replace(cloth, layers=layers)
        grip = self._grip(jobs, batch, x_init, bodies)
        if grip is not None:
            cloth = replace(cloth, grip=grip)
        stitches = self._stitches(jobs, batch)
        if stitches is not None:
            cloth = replace(cloth, stitches=stitches)
        return DrapeInput(batch, cloth, x_init, bodies, body_of_job[batch.vert_garment])

    def _in_layer_order(self, jobs: Sequence[Job], posed: PosedBodies, batch: GarmentBatch, x_init: Tensor,
                        layers: LayerOrder, bodies: BodySurface) -> tuple[Tensor, LayerOrder]:
        """X_init with each layered job's outer pieces pushed out over their inner ones
        (`physics.layers.push_outer_out`), and the layer order built on it.

        X_init's compression bound (`SkinningTransfer.min_stretch`) pushes compressed edges apart
        after the skinning; where a pose bends overlapping pieces (a raised arm over a jacket's
        side), that can carry one piece through another where the layer pairs, pushed out
        afterwards, do not hold them. So a skinned job whose pushed X_init has piece crossings
        (`geometry.intersections.piece_crossings`) is skinned again without the bound and takes
        that start where it crosses fewer face pairs; every other job keeps its X_init."""
        pushed = push_outer_out(x_init, layers)
        crossing = {k: n for k in self._unbounded_candidates(jobs)
                    if (n := self._piece_crossings(jobs[k], batch, pushed, k)) > 0}
        if not crossing:
            return pushed, layers
        other = x_init.clone()
        for k in crossing:
            other[_rows(batch, k)] = self.x_init(jobs[k].template, posed, jobs[k].body, jobs[k].rest,
                                      limits={"min_stretch": None}).to(x_init.dtype)
        other_layers = self._layers(jobs, batch, other, bodies)
        other_pushed = push_outer_out(other, other_layers)
        worse = [k for k, n in crossing.items() if self._piece_crossings(jobs[k], batch, other_pushed, k) >= n]
        if len(worse) == len(crossing):
            return pushed, layers
        if worse:  # the jobs whose start did not improve keep theirs; the layer order follows the starts
            for k in worse:
                other[_rows(batch, k)] = x_init[_rows(batch, k)]
            other_layers = self._layers(jobs, batch, other, bodies)
            other_pushed = push_outer_out(other, other_layers)
        return other_pushed, other_layers

    def _unbounded_candidates(self, jobs: Sequence[Job]) -> list[int]:
        """The jobs `_in_layer_order` may skin again without X_init's compression bound: layered,
        skinned here (no start of their own), under a transfer that bounds compression."""
        return [k for k, job in enumerate(jobs)
                if job.layers and job.x_init is None and self.transfer(job.template).min_stretch is not None]

    def _piece_crossings(self, job: Job, batch: GarmentBatch, x: Tensor, k: int) -> int:
        """Face pairs of different pieces of job `k` that intersect at its rows of `x`."""
        return piece_crossings(x[_rows(batch, k)].detach().to("cpu", torch.float64).numpy(), job.template.faces,
                               self._parts(job.template).piece)

    def _x_inits(self, jobs: Sequence[Job], posed: PosedBodies) -> dict[int, Tensor]:
        """X_init of every job that brings no start of its own, by job index.

        On the CPU with more than one torch thread, the jobs of different bodies are skinned and
        limited in parallel (each job's work is its own; the jobs of one body share that body's
        surface and its kept searches, so they run in turn); the first job runs alone first, so
        that what is built on first use (transfers, kernels, surfaces) is built once. Otherwise
        the jobs of one template on every body of the batch (a garment on many poses) are skinned
        and limited together, as one batch of meshes (`SkinningTransfer.apply` on all the bodies:
        the launches and searches of one job, not of each), and the others one by one. Each way
        gives every job the X_init it gets alone (on the CPU bit for bit)."""
        todo = [i for i, job in enumerate(jobs) if job.x_init is None]

        def run(indices: list[int]) -> dict[int, Tensor]:
            return {i: self.x_init(jobs[i].template, posed, jobs[i].body, jobs[i].rest) for i in indices}

        if not todo:
            return {}
        by_body: dict[int, list[int]] = {}
        for i in todo:
            by_body.setdefault(jobs[i].body, []).append(i)
        workers = min(torch.get_num_threads(), len(by_body))
        if workers < 2 or self.device.type != "cpu":
            out = self._x_inits_together(jobs, todo, posed)
            out.update(run([i for i in todo if i not in out]))
            return out
        out = run(todo[:1])
        for i in todo[1:]:  # first use outside the threads: fitted transfers, selected surfaces
            self.transfer(jobs[i].template)
            posed.single(jobs[i].body, self.dtype, self.device)
        by_body[jobs[todo[0]].body].remove(todo[0])
        for part in parallel_map(run, [part for part in by_body.values() if part], "x-init", workers):
            out.update(part)
        return out

    def _x_inits_together(self, jobs: Sequence[Job], todo: list[int], posed: PosedBodies) -> dict[int, Tensor]:
        """X_init of the jobs in `todo` whose template (on its own rest shape) is draped on every
        body of a batch of several, each template's as one batch over the bodies, by job index."""
        everyone = list(range(posed.state.batch_size))
        by_template: dict[str, list[int]] = {}
        for i in todo:
            if jobs[i].rest is None:
                by_template.setdefault(jobs[i].template.key, []).append(i)
        out = {}
        for indices in by_template.values():
            if len(everyone) < 2 or sorted({jobs[i].body for i in indices}) != everyone:
                continue
            with torch.no_grad():
                x = self._transfer_here(jobs[indices[0]].template).apply(
                    posed.state_on(self.device), surface=posed.surface(self.dtype, self.device))
            out.update({i: x[jobs[i].body] for i in indices})
        return out

    def grip_band(self, template: Template) -> np.ndarray:
        """The template's gripping vertices, its waistband's strip (`garments.pieces.waistband_band`),
        (K,) int64 (computed once)."""
        return self._bands.get(template.key, lambda: waistband_band(template.verts, self._parts(template)))

    def closure_pairs(self, template: Template) -> np.ndarray:
        """Where the template's panels overlap on the canonical body, the trousers' overlap with a
        top left out (`garments.closures.panel_overlaps`): the pairs closures tie, (K, 2) int64
        (computed once)."""
        def find() -> np.ndarray:
            parts = self._parts(template)
            exclude = None if parts.lower is None else parts.piece == parts.lower
            return panel_overlaps(template.verts, template.faces, parts.piece, exclude=exclude)

        return self._closures.get(template.key, find)

    def _stitches(self, jobs: Sequence[Job], batch: GarmentBatch) -> Stitches | None:
        """The batch's stitches: each job's pairs, rest distance on its rest shape, stiffness
        `DEFAULT_STITCH_STIFFNESS`; None when no job has any."""
        parts = []
        for k, job in enumerate(jobs):
            if job.stitches is None or len(job.stitches) == 0:
                continue
            pairs = torch.as_tensor(np.asarray(job.stitches, np.int64), device=batch.device)
            rest = batch.rest[batch.vert_offsets[k] + pairs]
            parts.append(Stitches(pairs=pairs + batch.vert_offsets[k], rest=(rest[:, 0] - rest[:, 1]).norm(dim=-1),
                                  stiffness=torch.full((len(pairs),), DEFAULT_STITCH_STIFFNESS, dtype=batch.dtype,
                                                       device=batch.device)))
        return Stitches.cat(parts) if parts else None

    def worn_job(self, template: Template, body: int, material, x_init: Tensor | None = None) -> Job:
        """A job of `template` worn as `Draper.drape` wears it by default, without sizing or
        closures (what training drapes): a garment with a lower piece (an outfit, trousers) has
        its waistband gripped (`physics.grip`, the default κ), one of several pieces has them kept
        in layer order; a one-piece top has neither to grip nor to order."""
        parts = self._parts(template)
        if parts.lower is None:
            return Job(template, body, material, x_init)
        return Job(template, body, material, x_init, grip=DEFAULT_GRIP_STIFFNESS, layers=parts.num_pieces > 1)

    def _parts(self, template: Template) -> GarmentParts:
        """The template's pieces (`garments.pieces.garment_parts`; found once)."""
        return self._pieces.get(template.key, lambda: garment_parts(template.verts, template.faces))

    def layer_pairs(self, template: Template) -> np.ndarray:
        """[outer, inner] vertex pairs where the template's pieces overlap on the canonical body
        (`garments.layering.layer_pairs`), (P, 2) int64 (computed once)."""
        return self._layering(template).pairs

    def _layering(self, template: Template) -> layering.LayerPairs:
        """The template's layer pairs and their separation on it [m] (`layering.layer_pairs`)."""
        def find() -> layering.LayerPairs:
            body_verts = self.body.canonical_verts(dtype=torch.float64).numpy()
            return layering.layer_pairs(template.verts, self._parts(template).piece, body_verts,
                                        np.asarray(self.body.faces, np.int64))

        return self._layer_pairs.get(template.key, find)

    def _layers(self, jobs: Sequence[Job], batch: GarmentBatch, x_init: Tensor, bodies: BodySurface) -> LayerOrder | None:
        """The batch's layer order: each layered job's pairs, the body normal at the inner vertex
        at X_init, the gap each pair has on the template (`LayerOrder.build`), stiffness
        `DEFAULT_LAYER_STIFFNESS`, and what `physics.layers.follow_pairs` needs to complete the
        pairs where the pieces are (each vertex's piece numbered across the batch, which pieces are
        one garment's, the template's body distances, the faces); None when none."""
        layered = [(k, self._layering(job.template)) for k, job in enumerate(jobs) if job.layers]
        layered = [(k, found) for k, found in layered if len(found.pairs)]
        if not layered:
            return None
        device = batch.device
        pairs = torch.cat([torch.as_tensor(f.pairs, device=device) + batch.vert_offsets[k] for k, f in layered])
        separation = torch.cat([torch.as_tensor(f.separation, dtype=x_init.dtype, device=device) for _, f in layered])
        piece = torch.full((batch.num_verts,), -1, dtype=torch.int64, device=device)
        depth = torch.zeros(batch.num_verts, dtype=x_init.dtype, device=device)
        together = torch.block_diag(*(torch.ones(len(f.over), len(f.over)) for _, f in layered)).to(device).bool()
        first = 0
        for k, found in layered:
            start, stop = int(batch.vert_offsets[k]), int(batch.vert_offsets[k + 1])
            piece[start:stop] = torch.as_tensor(self._parts(jobs[k].template).piece, device=device) + first
            depth[start:stop] = torch.as_tensor(found.depth, dtype=x_init.dtype, device=device)
            first += len(found.over)
        faces = torch.cat([batch.faces[batch.face_garment == k] for k, _ in layered])
        body_of_job = torch.tensor([job.body for job in jobs], dtype=torch.int64, device=device)
        inner = pairs[:, 1]
        with torch.no_grad():
            normal = bodies.query(x_init[inner].to(bodies.verts.dtype),
                                  body_index=body_of_job[batch.vert_garment[inner]]).normal
        order = LayerOrder.build(pairs, normal.to(x_init.dtype), separation=separation)
        return replace(order, piece=piece, together=together, depth=depth, faces=faces)

    def _grip(self, jobs: Sequence[Job], batch: GarmentBatch, x_init: Tensor, bodies: BodySurface) -> Grip | None:
        """The batch's grip: each gripping job's waistband strip anchored at X_init, tangentially to
        the body there, k_i = κ · (vertex area); None when no job grips."""
        index = [torch.as_tensor(self.grip_band(job.template), device=batch.device) + batch.vert_offsets[k]
                 for k, job in enumerate(jobs) if job.grip > 0]
        if not any(len(i) for i in index):
            return None
        kappa = torch.cat([torch.full((len(self.grip_band(job.template)),), float(job.grip), dtype=x_init.dtype,
                                      device=batch.device) for job in jobs if job.grip > 0])
        index = torch.cat(index)
        area = torch.zeros(batch.num_verts, dtype=x_init.dtype, device=batch.device).index_add_(
            0, batch.faces.reshape(-1), (batch.rest_area.to(x_init.dtype) / 3.0).repeat_interleave(3))
        body_of_vertex = torch.tensor([job.body for job in jobs], dtype=torch.int64,
                                      device=batch.device)[batch.vert_garment]
        with torch.no_grad():
            normal = bodies.query(x_init[index].to(bodies.verts.dtype), body_index=body_of_vertex[index]).normal
        return Grip(index=index, anchor=x_init[index].detach().clone(), normal=normal.to(x_init.dtype),
                    stiffness=kappa * area[index])

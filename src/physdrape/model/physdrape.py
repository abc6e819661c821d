"""PhysDrape: force-driven GNN → learnable stretching solver → collision handler (paper Sec. 3)."""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, replace

import torch
from torch import Tensor, nn

from physdrape.geometry.distance_bound import DistanceBound
from physdrape.geometry.garment import GarmentBatch, GraphLevels
from physdrape.geometry.proximity import BodySurface, SurfaceQuery
from physdrape.model.collision_handler import CollisionHandler
from physdrape.model.config import Displacement, ModelConfig, Variant
from physdrape.model.features import (
    BODY_FEATURES,
    EDGE_FEATURES,
    NEWTON_FEATURES,
    NODE_FEATURES,
    STEP_FEATURES,
    edge_features,
    node_features,
)
from physdrape.model.gnn import EncodeProcessDecode
from physdrape.model.normalizer import Normalizer
from physdrape.model.stretching_solver import StretchingSolver, clip_moves
from physdrape.physics.cloth import Cloth
from physdrape.physics.contact import query_samples_near
from physdrape.physics.layers import layer_shortfall, push_outer_out

#: The layer pairs' tangential share β in the preconditioner of the solver's step that the network
#: reads (`ModelConfig.step_inputs`; the solver's own is `physics.forces.LAYER_SLIDE_DAMPING`): 0,
#: the pairs acting along their normals only, as the layer energy's Hessian does. The solver's β
#: slows the pieces' relative sliding over many steps, past which the template's pairs no longer
#: hold them apart; the network sees each piece alone, its move is pushed back out where it drives
#: one piece into the one under it, and its input should say where each piece is pulled. With the
#: solver's β the step's coarse moves are smaller on every piece of a layered suit, and the
#: network, which extrapolates that step, moves the pieces less (`results/layer_slide_damping_inputs.md`).
#: A garment of one piece has no layer pairs.
INPUT_LAYER_SLIDE = 0.0


@dataclass(frozen=True)
class DrapeInput:
    """One batch of draping problems (garment g is draped on body `body_index` of its vertices).

    Attributes:
        garments: packed garment templates; cloth: their physics coefficients (materials);
        x_init: kinematic initialisation X_init [m], (ΣV, 3);
        bodies: the posed bodies; body_index: body of each garment vertex, (ΣV,) int64;
        x_init_nodes: the network's raw node inputs at X_init (`PhysDrape.node_inputs`), where the
            caller holds them (a training instance's are the same at every step), or None: the
            model computes them.
    All on one device, the model's (`to` moves them).
    """

    garments: GarmentBatch
    cloth: Cloth
    x_init: Tensor
    bodies: BodySurface
    body_index: Tensor
    x_init_nodes: Tensor | None = None

    @property
    def device(self) -> torch.device:
        return self.x_init.device

    def to(self, device: torch.device | str) -> DrapeInput:
        """The same batch on `device` (the body surface rebuilds its BVHs there)."""
        return DrapeInput(self.garments.to(device=device), self.cloth.to(device=device), self.x_init.to(device),
                          self.bodies.to(device), self.body_index.to(device),
                          None if self.x_init_nodes is None else self.x_init_nodes.to(device))


@dataclass(frozen=True)
class DrapeOutput:
    """x: the drape X* [m] (ΣV, 3); x_gnn: X_init + Δx (with the layer order kept, `PhysDrape.forward`);
    f_hat: f̂ [N] (ΣV, 3); trace: solver states; bound: the `DistanceBound` of the solver's last
    full body query (vertices, then face centroids; None without one), for later queries of x to
    skip what is far from the body; earlier_passes: with `ModelConfig.passes` > 1, X_init plus
    the moves of the passes before the last, one (ΣV, 3) per pass, and with
    `ModelConfig.look_back_blocks` each pass's drape before its look-back stage, in the order
    they were made (a loss on them trains each to drape on its own,
    `train.loss.LossConfig.earlier_passes_weight`)."""

    x: Tensor
    x_gnn: Tensor
    f_hat: Tensor
    trace: tuple[Tensor, ...]
    bound: DistanceBound | None = None
    earlier_passes: tuple[Tensor, ...] = ()


#: The most vertices the network processes as one piece of a batch (`network_parts`): a
#: T-shirt's latents (3k vertices x 32 floats, six times as many edges) fit a core's caches.
PART_VERTICES = 4096


def network_parts(offsets: list[int], most: int = PART_VERTICES) -> list[int]:
    """Vertex bounds [0, …, ΣV] of consecutive garments grouped into pieces of at most `most`
    vertices (a larger garment is a piece alone), from the batch's garment offsets [0, …, ΣV]."""
    bounds = [offsets[0]]
    for start, stop in itertools.pairwise(offsets):
        if stop - bounds[-1] > most and start > bounds[-1]:
            bounds.append(start)
    return bounds + [offsets[-1]] if offsets[-1] > bounds[-1] else bounds


def summary_groups(batch: DrapeInput) -> Tensor:
    """Each vertex's summary group (ΣV,) int64 (`ModelConfig.global_context`): its piece where its
    garment has a layer order of pieces (a suit's jacket and trousers each summarised on their
    own, as the single garments the network is trained on), else its garment."""
    garment = batch.garments.vert_garment
    layers = batch.cloth.layers
    if layers is None or layers.piece is None:
        return garment
    return torch.where(layers.piece >= 0, layers.piece + len(batch.garments.vert_offsets), garment)


class PhysDrape(nn.Module):
    """The PhysDrape model; `config.variant` selects the ablation."""

    def __init__(self, config: ModelConfig = ModelConfig()) -> None:
        super().__init__()
        self.config = config
        node_in = NODE_FEATURES + (BODY_FEATURES if config.body_normal_inputs else 0)
        node_in += STEP_FEATURES if config.step_inputs else 0
        node_in += NEWTON_FEATURES if config.step_newton_iterations else 0
        self.node_normalizer = Normalizer(node_in, max_accumulations=config.normalizer_accumulations)
        edge_in = EDGE_FEATURES + (config.levels + 1 if config.levels else 0)
        self.edge_normalizer = Normalizer(edge_in, max_accumulations=config.normalizer_accumulations)
        self.gnn = EncodeProcessDecode(
            node_in, edge_in, 6, latent=config.latent, blocks=config.blocks, mlp_layers=config.mlp_layers,
            levels=config.levels, zero_init_output=config.zero_init_output,
            look_back_in=STEP_FEATURES, look_back_blocks=config.look_back_blocks, mesh_blocks=config.mesh_blocks,
            global_context=config.global_context,
        )
        self.solver = StretchingSolver(kind=config.solver, eta=config.eta, gamma=config.gamma, max_step=config.max_step,
                                       margin=config.margin, contact_stiffness=config.contact_stiffness,
                                       requery_every=config.requery_every, refactor_every=config.refactor_every,
                                       refactor_first=config.refactor_first, follow_planes=config.follow_planes,
                                       eval_requery_every=config.eval_requery_every,
                                       eval_follow_planes=config.eval_follow_planes, f_hat_steps=config.f_hat_steps,
                                       follow_min_move=config.follow_min_move, inner_steps=config.inner_steps,
                                       inner_iterations=config.inner_iterations,
                                       eval_inner_iterations=config.eval_inner_iterations,
                                       coarse_levels=config.coarse_levels,
                                       coarse_smoothing=config.coarse_smoothing, contact_band=config.contact_band,
                                       eval_contact_band=config.eval_contact_band)
        self.handler = CollisionHandler(margin=config.margin, delta=config.delta, centroid_margin=config.centroid_margin)

    def set_eval_planes(self, follow: bool) -> None:
        """The solver's body planes in eval mode followed between body searches (every
        eval_requery_every steps), or held between them as in training (every requery_every
        steps); config and solver alike."""
        every = self.config.eval_requery_every if follow else self.config.requery_every
        self.config = replace(self.config, eval_follow_planes=bool(follow), eval_requery_every=every)
        self.solver.eval_follow_planes, self.solver.eval_requery_every = bool(follow), every

    def graph_inputs(self, batch: DrapeInput, x: Tensor | None = None) -> tuple[Tensor, Tensor, GraphLevels]:
        """Raw (un-normalised) node and edge features at x (default X_init), in the network's
        dtype, and the graph they live on (the mesh edges, plus `config.levels` coarse levels);
        with `config.body_normal_inputs`, the body's normal under each vertex follows the node
        features; with `config.step_inputs`, the nodes' last columns are the solver's first step parts at x
        (and its truncated Newton move, with `config.step_newton_iterations`)."""
        return self._graph_inputs(batch, x)[:3]

    def _graph_inputs(self, batch: DrapeInput,
                      x: Tensor | None = None) -> tuple[Tensor, Tensor, GraphLevels, SurfaceQuery | None]:
        """`graph_inputs` and, with `config.step_inputs`, the body query of x's contact samples
        that its step parts were found on (else None; also where the batch holds the node inputs
        at X_init and no look-back stage reads the query)."""
        x = batch.x_init if x is None else x
        net_dtype = self.gnn.decoder[0].weight.dtype
        if x is batch.x_init and batch.x_init_nodes is not None and not self.config.look_back_blocks:
            nodes, query = batch.x_init_nodes, None
        else:
            nodes, query = self._node_inputs(batch, x)
        nodes = nodes.to(net_dtype)
        levels = self.config.levels
        graph = batch.garments.graph_levels(levels)
        edges = edge_features(x, batch.garments, graph.edge_index, graph.level, levels)
        return nodes, edges.to(net_dtype), graph, query

    @torch.no_grad()
    def node_inputs(self, batch: DrapeInput, x: Tensor | None = None) -> Tensor:
        """The network's raw (un-normalised) node inputs at x (default X_init), in x's dtype: the
        node features (`model.features.node_features`) and, with `config.step_inputs`, the
        two-level solver's first-step parts there (`StretchingSolver.step_parts`)."""
        return self._node_inputs(batch, batch.x_init if x is None else x)[0]

    def _node_inputs(self, batch: DrapeInput, x: Tensor) -> tuple[Tensor, SurfaceQuery | None]:
        """`node_inputs` and, with `config.step_inputs`, the body query of x's contact samples."""
        if not self.config.step_inputs:
            query = batch.bodies.query(x, body_index=batch.body_index)
            nodes = node_features(x, batch.garments, batch.cloth, query.signed_distance)
            return self._with_body_normals(nodes, query), None
        # one body query serves the vertices' distances and the step's contact: the face centroids
        # only within the contact's reach (no contact term or block sees the others)
        reach = max(self.solver.contact_band, self.solver.margin)
        query = query_samples_near(x.detach(), batch.cloth.faces, batch.bodies, batch.body_index, reach=reach)
        nodes = node_features(x, batch.garments, batch.cloth, query.signed_distance[:x.shape[0]].to(x.dtype))
        nodes = self._with_body_normals(nodes, query)
        parts = self.solver.step_parts(x.detach(), batch.cloth, bodies=batch.bodies, body_index=batch.body_index,
                                       query=query, newton_iterations=self.config.step_newton_iterations,
                                       layer_slide=INPUT_LAYER_SLIDE)
        return torch.cat([nodes, *(part.to(nodes.dtype) for part in parts)], dim=-1), query

    def _with_body_normals(self, nodes: Tensor, query: SurfaceQuery) -> Tensor:
        """The node features (ΣV, 11) and, with `config.body_normal_inputs`, the body's outward
        direction at each vertex's closest point (the first ΣV rows of the query)."""
        if not self.config.body_normal_inputs:
            return nodes
        return torch.cat([nodes, query.normal[:nodes.shape[0]].to(nodes.dtype)], dim=-1)

    def _look_back(self, batch: DrapeInput, at: Tensor, query: SurfaceQuery) -> Callable[[Tensor], Tensor]:
        """The look-back stage's reader (`EncodeProcessDecode.forward_looking_back`): the network's
        output y₁ → the two-level solver's first step parts (local, coarse) at at + Δx₁ on the body
        planes of `query` (x's, held: the network moves the garment millimetres to a few
        centimetres), normalised with the node normaliser's statistics of the step inputs (the same
        quantities, where the network's input found them), (ΣV, 6); not differentiated."""
        def read(first: Tensor) -> Tensor:
            with torch.no_grad():
                moved = at + self.config.displacement_scale * first[:, :3].to(at.dtype)
                local, coarse = self.solver.step_parts(moved, batch.cloth, bodies=batch.bodies,
                                                       body_index=batch.body_index, query=query,
                                                       layer_slide=INPUT_LAYER_SLIDE)
                parts = torch.cat([local, coarse], dim=-1).to(first.dtype)
                return self.node_normalizer.normalize_columns(parts, slice(-STEP_FEATURES, None))
        return read

    @torch.no_grad()
    def accumulate_statistics(self, batch: DrapeInput) -> None:
        """One batch of the normalisers' statistics-only warm-up."""
        nodes, edges, _ = self.graph_inputs(batch)
        self.node_normalizer.accumulate(nodes)
        self.edge_normalizer.accumulate(edges)

    def forward(self, batch: DrapeInput, *, steps: int | None = None, keep_trace: bool = False) -> DrapeOutput:
        """Drape a batch. steps: solver steps T (default: train_steps in training, else eval_steps).

        The network's move X_init + Δx keeps a multi-piece garment's layer order
        (`physics.layers.push_outer_out`): the network sees each piece alone (no graph edge joins
        two pieces), so its move can drive an outer piece into the one under it. In eval mode the
        solver starts from X_init + g Δx, g = `ModelConfig.eval_move_gain` (the output's x_gnn is
        the network's drape X_init + Δx whatever g)."""
        cfg = self.config
        # forces in units of each vertex's weight: the support a vertex needs is of that order
        weight = batch.cloth.mass * batch.cloth.gravity[batch.cloth.vert_garment].norm(dim=-1)
        x_gnn, earlier = batch.x_init, []
        for k in range(cfg.passes):
            if k:
                earlier.append(x_gnn)
            # a later pass reads its inputs at the garment the passes before it moved (forces,
            # normals, body distances, edges there), held constant in the gradient: it learns to
            # correct what it sees, and the earlier passes are trained through its move (and,
            # with loss.earlier_passes_weight, through their own drapes)
            at = x_gnn if k == 0 else x_gnn.detach()
            nodes, edges, graph, query = self._graph_inputs(batch, at)
            parts = network_parts(batch.garments.vert_offsets.tolist())
            groups = summary_groups(batch) if cfg.global_context else None
            nodes, edges = self.node_normalizer(nodes), self.edge_normalizer(edges)
            if cfg.look_back_blocks:
                first, out = self.gnn.forward_looking_back(nodes, edges, graph, self._look_back(batch, at, query),
                                                           parts=parts, groups=groups)
                earlier.append(x_gnn + cfg.displacement_scale * first[:, :3].to(at.dtype))
            else:
                out = self.gnn(nodes, edges, graph, parts=parts, groups=groups)
            out = out.to(at.dtype)
            if cfg.displacement is Displacement.PRECONDITIONED:
                precondition = self.solver.preconditioner(at.detach(), batch.cloth, bodies=batch.bodies,
                                                          body_index=batch.body_index)
                delta_x = clip_moves(precondition(cfg.force_scale * out[:, :3] * weight[:, None]), cfg.max_move)
            else:
                delta_x = cfg.displacement_scale * out[:, :3]
            x_gnn = x_gnn + delta_x
        f_hat = out[:, 3:] * weight[:, None]  # the last pass's
        start = x_gnn
        if cfg.variant.uses_solver and not self.training and cfg.eval_move_gain != 1.0:
            # the solver starts from the network's move extrapolated (ModelConfig.eval_move_gain)
            start = batch.x_init + cfg.eval_move_gain * (x_gnn - batch.x_init)
        layers = batch.cloth.layers
        if layers is not None and len(layers.pairs):
            # the network sees each piece alone: where its move drove an outer piece into the one
            # under it, the outer vertex goes back out, so the move adds nothing to a pair's
            # layer-order shortfall over X_init's (as the collision handler's layer pass)
            allowed = layer_shortfall(batch.x_init, layers)
            extrapolated = start is not x_gnn
            x_gnn = push_outer_out(x_gnn, layers, allowed=allowed)
            start = push_outer_out(start, layers, allowed=allowed) if extrapolated else x_gnn
        out = self._physics(batch, start, f_hat, steps=steps, keep_trace=keep_trace)
        return replace(out, x_gnn=x_gnn, earlier_passes=tuple(earlier))

    def physics_only(self, batch: DrapeInput, *, steps: int | None = None, keep_trace: bool = False) -> DrapeOutput:
        """The model's solver steps (Δx = 0, f̂ = 0) and collision handler from X_init, without the
        network pass: the warm-start continuation of a sequence, and the evaluation's measure of
        what the network adds. Modules as in `forward` for the configured variant."""
        return self._physics(batch, batch.x_init, torch.zeros_like(batch.x_init), steps=steps, keep_trace=keep_trace)

    def _physics(self, batch: DrapeInput, x_gnn: Tensor, f_hat: Tensor, *, steps: int | None,
                 keep_trace: bool) -> DrapeOutput:
        """The variant's solver and handler from the network's output x_gnn (ΣV, 3) and f̂."""
        cfg = self.config
        x, trace, bounds = x_gnn, [], []
        if cfg.variant.uses_solver:
            if steps is None:
                steps = cfg.train_steps if self.training else cfg.eval_steps
            x = self.solver(x, batch.cloth, f_hat=f_hat, steps=steps, trace=trace if keep_trace else None,
                            bodies=batch.bodies, body_index=batch.body_index, bounds=bounds)
        bound = bounds[0] if bounds else None
        if cfg.variant.uses_handler:
            x = self.handler(x, batch.bodies, batch.body_index, faces=batch.garments.faces, layers=batch.cloth.layers,
                             bound=bound)
        elif cfg.variant is Variant.POST_COL and not self.training:
            x = self.handler(x, batch.bodies, batch.body_index, delta=1.0, faces=batch.garments.faces,
                             layers=batch.cloth.layers, bound=bound)
        return DrapeOutput(x=x, x_gnn=x_gnn, f_hat=f_hat, trace=tuple(trace), bound=bound)

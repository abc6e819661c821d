"""The force-driven GNN (paper Eqs. 7–9): encode-process-decode on the garment mesh graph, with
optional hierarchical message passing over coarse graphs (HOOD-style) so that the network sees
the whole garment.

With K coarse levels the processor blocks walk V-cycles over the levels, 0, 1, …, K, …, 1, 0, …:
a block of level l passes messages along the level's edges between the level's nodes only (a
subset of the vertices about 2^l mesh edges apart) and leaves the other vertices' latents as
they are. One V-cycle of 2K + 1 blocks reaches about 2·(2^(K+1) − 1) mesh edges, at the cost of
little more than two blocks on the mesh, since level l has a few times fewer nodes and edges than
level l − 1.
"""

from __future__ import annotations

import itertools
import threading
import warnings
from collections.abc import Callable, Iterator

import torch
from torch import Tensor, nn

from physdrape.geometry.garment import GraphLevels


def mlp(in_size: int, hidden: int, out_size: int, *, layers: int = 2, layer_norm: bool = True) -> nn.Sequential:
    """`layers` Linear layers with ReLU between them, optionally closed by LayerNorm."""
    sizes = [in_size] + [hidden] * (layers - 1) + [out_size]
    modules: list[nn.Module] = []
    for k in range(layers):
        modules.append(nn.Linear(sizes[k], sizes[k + 1]))
        if k < layers - 1:
            modules.append(nn.ReLU())
    if layer_norm:
        modules.append(nn.LayerNorm(out_size))
    return nn.Sequential(*modules)


class ProcessorBlock(nn.Module):
    """One residual message-passing block (Eq. 8): edges first, then nodes by sum aggregation."""

    def __init__(self, latent: int, *, mlp_layers: int) -> None:
        super().__init__()
        self.edge_mlp = mlp(3 * latent, latent, latent, layers=mlp_layers)
        self.node_mlp = mlp(2 * latent, latent, latent, layers=mlp_layers)

    def forward(self, nodes: Tensor, edges: Tensor, edge_index: Tensor) -> tuple[Tensor, Tensor]:
        """edges += edge_mlp([e, h_receiver, h_sender]); nodes += node_mlp([h, Σ_receiver e]).

        The MLPs' first layers are applied to the parts of their inputs apart (`_column_blocks`):
        W [e, h_r, h_s] = W_e e + (W_r h)_r + (W_s h)_s projects each node once instead of once per
        edge (a mesh has about six times as many directed edges as nodes) and builds no
        concatenated copy of the inputs; the parameters are those of the concatenated form."""
        sender, receiver = edge_index[0], edge_index[1]
        w_edge, w_receiver, w_sender = _column_blocks(self.edge_mlp)
        first = (_linear(edges, w_edge, self.edge_mlp[0].bias) + _linear(nodes, w_receiver).index_select(0, receiver)
                 + _linear(nodes, w_sender).index_select(0, sender))
        edges = edges + self.edge_mlp[1:](first)
        aggregated = torch.zeros_like(nodes).index_add_(0, receiver, edges)
        w_node, w_incoming = _column_blocks(self.node_mlp)
        first = torch.addmm(_linear(nodes, w_node, self.node_mlp[0].bias), aggregated, w_incoming.t())
        nodes = nodes + self.node_mlp[1:](first)
        return nodes, edges


def _column_blocks(mlp_: nn.Sequential) -> tuple[Tensor, ...]:
    """An MLP's first weight cut into column blocks as wide as the latent (its output width): the
    weights of each part of the concatenated input."""
    weight = mlp_[0].weight
    return weight.split(weight.shape[0], dim=1)


def _linear(inputs: Tensor, weight: Tensor, bias: Tensor | None = None) -> Tensor:
    """inputs Wᵀ (+ bias)."""
    return nn.functional.linear(inputs, weight, bias)


#: One network compiles at a time (`EncodeProcessDecode.compile_network`: batch groups drape on parallel threads).
_COMPILE_LOCK = threading.Lock()


def level_schedule(blocks: int, levels: int) -> list[int]:
    """The graph level of each processor block: V-cycles 0, 1, …, levels, …, 1, 0, … (all 0 when
    levels = 0)."""
    if levels == 0:
        return [0] * blocks
    period = 2 * levels
    return [min(k % period, period - k % period) for k in range(blocks)]


class EncodeProcessDecode(nn.Module):
    """Encoders to a latent of width D, L processor blocks, a decoder without LayerNorm; optionally
    a look-back stage (`forward_looking_back`).

    Args:
        node_in, edge_in: raw (normalised) feature widths; out: decoder output width.
        latent: D; blocks: L; mlp_layers: Linear layers per MLP (the paper: 2).
        levels: coarse graph levels the blocks walk (`level_schedule`); 0: the mesh graph only.
        mesh_blocks: more blocks on the mesh graph after those (local work on what the V-cycles
            gathered), each starting as the identity (its MLPs' last layers at zero), so that
            they can be added to a trained network without changing its output.
        zero_init_output: start the decoder's last layer at zero (an untrained network outputs 0).
        look_back_in, look_back_blocks: the look-back stage's feature width and its blocks (an
            odd number, a V-cycle over (look_back_blocks − 1) / 2 levels at most `levels`; 0:
            no stage). Its decoder starts at zero: the stage adds nothing until trained.
        global_context: after each processor block every node's latent also gets its group's
            summary (its garment's, or its piece's of a multi-piece garment: `forward`'s groups),
            an MLP of the mean of the group's node latents (one MLP per block): what the whole
            piece does reaches every vertex at once, beyond the V-cycles' reach. Each MLP's last
            layer starts at zero, so that the summaries can be added to a trained network
            without changing its output.
    Forward: nodes (N, node_in), edges (E', edge_in) of all levels in `graph.edge_index`'s order,
    graph (`GraphLevels` with at least `levels` coarse levels) → (N, out).
    """

    def __init__(self, node_in: int, edge_in: int, out: int, *, latent: int, blocks: int, mlp_layers: int = 2,
                 levels: int = 0, zero_init_output: bool = False, look_back_in: int = 0,
                 look_back_blocks: int = 0, mesh_blocks: int = 0, global_context: bool = False) -> None:
        super().__init__()
        self.schedule = level_schedule(blocks, levels) + [0] * mesh_blocks
        self.node_encoder = mlp(node_in, latent, latent, layers=mlp_layers)
        self.edge_encoder = mlp(edge_in, latent, latent, layers=mlp_layers)
        self.blocks = nn.ModuleList(ProcessorBlock(latent, mlp_layers=mlp_layers) for _ in self.schedule)
        for block in self.blocks[blocks:]:  # identity at the start: edges += 0, nodes += 0
            for last in (block.edge_mlp[-2], block.node_mlp[-2]):
                nn.init.zeros_(last.weight)
                nn.init.zeros_(last.bias)
        self.global_mlps = (nn.ModuleList(mlp(latent, latent, latent, layers=mlp_layers, layer_norm=False)
                                          for _ in self.schedule) if global_context else None)
        for summary in self.global_mlps or ():  # no summary at the start: h += 0
            nn.init.zeros_(summary[-1].weight)
            nn.init.zeros_(summary[-1].bias)
        self.decoder = mlp(latent, latent, out, layers=mlp_layers, layer_norm=False)
        if zero_init_output:  # the untrained network outputs 0: training starts from its input state
            nn.init.zeros_(self.decoder[-1].weight)
            nn.init.zeros_(self.decoder[-1].bias)
        self._compiled: Callable | None = None  # `compile_network`'s encoders and blocks
        self._compile_pending: set[bool] = set()  # the grad modes not yet run compiled (each compiles)
        self.look_back_schedule = (level_schedule(look_back_blocks, min(levels, (look_back_blocks - 1) // 2))
                                   if look_back_blocks else [])
        if look_back_blocks:
            self.look_back_encoder = mlp(look_back_in, latent, latent, layers=mlp_layers)
            self.look_back_blocks = nn.ModuleList(ProcessorBlock(latent, mlp_layers=mlp_layers)
                                                  for _ in range(look_back_blocks))
            self.look_back_decoder = mlp(latent, latent, out, layers=mlp_layers, layer_norm=False)
            nn.init.zeros_(self.look_back_decoder[-1].weight)
            nn.init.zeros_(self.look_back_decoder[-1].bias)

    def compile_network(self) -> None:
        """Run the encoders and processor blocks compiled by `torch.compile` from now on: TorchInductor
        fuses the blocks' small matrix products, LayerNorms, ReLUs and gathers into a few loops
        (and, where a gradient is recorded, their backward). With dynamic shapes one compilation
        serves every garment size; inference and training each compile their own graph on first
        use (tens of seconds; TorchInductor caches its kernels on disk, so later processes take
        seconds). Where compiling fails (no C++ compiler, no Triton for a GPU), a warning says so
        and the network runs eagerly. The compiled graph computes what the eager one does, up to
        the rounding of fused float operations."""
        self._compiled = torch.compile(self._encoded_and_processed, dynamic=True)
        self._compile_pending = {False, True}

    def forward(self, nodes: Tensor, edges: Tensor, graph: GraphLevels, parts: list[int] | None = None,
                groups: Tensor | None = None) -> Tensor:
        """parts: vertex bounds [0, b₁, …, N] of pieces no edge crosses (whole garments of a
        batch), processed one after the other: the same output, with each piece's latents small
        enough to stay in the CPU's caches (a batch of garments as one graph runs about half as
        fast per garment on one thread). None: the graph in one piece. groups: each node's
        summary group (N,) int64 (`global_context`: a number per garment or piece, any numbers,
        no group across parts); None: one group."""
        outs = [self.decoder(h) for h, _, _ in self._processed(nodes, edges, graph, parts, groups)]
        return outs[0] if len(outs) == 1 else torch.cat(outs)

    def forward_looking_back(self, nodes: Tensor, edges: Tensor, graph: GraphLevels,
                             look_back: Callable[[Tensor], Tensor], parts: list[int] | None = None,
                             groups: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """The network's output before and after its look-back stage, each (N, out): the blocks'
        output y₁ as `forward` makes it; then `look_back`(y₁) → (N, look_back_in) features read
        where y₁ moves the garment (the caller's physics, normalised), encoded and added to the
        latents, the look-back blocks on the mesh and coarse edges' latents as the blocks left
        them, and y₁ + the look-back decoder's output. parts, groups: as `forward` (the
        look-back reads the whole batch at once, between the two stages; its blocks take no
        summaries)."""
        if not self.look_back_schedule:
            raise ValueError("this network has no look-back stage (ModelConfig.look_back_blocks = 0)")
        pieces = list(self._processed(nodes, edges, graph, parts, groups))
        first = [self.decoder(h) for h, _, _ in pieces]
        first_out = torch.cat(first)
        features = torch.split(look_back(first_out), [len(y) for y in first])
        second = []
        for (h, e, sub), extra in zip(pieces, features):
            h = h + self.look_back_encoder(extra)
            h, _ = self._blocks(self.look_back_blocks, self.look_back_schedule, h, e, sub, None)
            second.append(self.look_back_decoder(h))
        return first_out, first_out + torch.cat(second)

    def _processed(self, nodes: Tensor, edges: Tensor, graph: GraphLevels, parts: list[int] | None,
                   groups: Tensor | None) -> Iterator[tuple[Tensor, list[Tensor], GraphLevels]]:
        """Per piece (`forward`'s parts), one after the other, its node latents, its edge latents
        per level and its graph after the encoders and the processor blocks (a generator: a
        caller that decodes each piece as it comes holds one piece's latents at a time)."""
        run = self._encoded_and_processed if self._compiled is None else self._run_compiled
        if parts is None or len(parts) <= 2:
            yield run(nodes, edges, graph, *self._summary_groups(groups, 0, len(nodes)))
            return
        per_level = torch.split(edges, graph.edge_counts)
        for start, stop in itertools.pairwise(parts):
            sub, chosen = graph.part(start, stop)
            piece_edges = torch.cat([e[k] for e, k in zip(per_level, chosen)])
            yield run(nodes[start:stop], piece_edges, sub, *self._summary_groups(groups, start, stop))

    def _summary_groups(self, groups: Tensor | None, start: int,
                        stop: int) -> tuple[Tensor | None, Tensor | None]:
        """The nodes start…stop's summary groups numbered from 0 and each group's node count, found
        once for every block (None, None: no summaries, or one group)."""
        if self.global_mlps is None or groups is None:
            return None, None
        _, group, sizes = torch.unique(groups[start:stop], return_inverse=True, return_counts=True)
        return group, sizes

    def _run_compiled(self, nodes: Tensor, edges: Tensor, graph: GraphLevels, group: Tensor | None = None,
                      sizes: Tensor | None = None) -> tuple[Tensor, list[Tensor], GraphLevels]:
        """`_encoded_and_processed` compiled (`compile_network`); the first call in each grad mode
        compiles, one thread at a time, and falls back to eager for good where compiling fails."""
        mode = torch.is_grad_enabled()
        if mode in self._compile_pending:
            with _COMPILE_LOCK:
                if self._compiled is not None and mode in self._compile_pending:
                    try:
                        out = self._compiled(nodes, edges, graph, group, sizes)
                    except Exception as exc:  # noqa: BLE001 - any backend failure: run eagerly instead
                        warnings.warn(f"torch.compile could not compile the network ({type(exc).__name__}: "
                                      f"{str(exc).splitlines()[0] if str(exc) else ''}); it runs eagerly", stacklevel=2)
                        self._compiled = None
                        out = self._encoded_and_processed(nodes, edges, graph, group, sizes)
                    self._compile_pending.discard(mode)
                    return out
        if self._compiled is None:
            return self._encoded_and_processed(nodes, edges, graph, group, sizes)
        return self._compiled(nodes, edges, graph, group, sizes)

    def _encoded_and_processed(self, nodes: Tensor, edges: Tensor, graph: GraphLevels, group: Tensor | None = None,
                               sizes: Tensor | None = None) -> tuple[Tensor, list[Tensor], GraphLevels]:
        h = self.node_encoder(nodes)
        e = list(torch.split(self.edge_encoder(edges), graph.edge_counts))
        summaries = None if self.global_mlps is None else (self.global_mlps, group, sizes)
        h, e = self._blocks(self.blocks, self.schedule, h, e, graph, summaries)
        return h, e, graph

    @staticmethod
    def _blocks(blocks: nn.ModuleList, schedule: list[int], h: Tensor, e: list[Tensor], graph: GraphLevels,
                summaries: tuple[nn.ModuleList, Tensor | None, Tensor | None] | None) -> tuple[Tensor, list[Tensor]]:
        """Run `blocks` at the levels of `schedule`: a block of level l passes messages among the
        level's nodes along its edges and leaves the other nodes' latents as they are. summaries:
        (one MLP per block, each node's group from 0 and each group's node count, or None, None
        for one group): after each block every node adds its group's summary (`global_context`)."""
        e = list(e)
        for k, (block, level) in enumerate(zip(blocks, schedule)):
            if level == 0:
                h, e[0] = block(h, e[0], graph.local_edge_index[0])
            else:
                ids = graph.nodes[level]
                sub, e[level] = block(h[ids], e[level], graph.local_edge_index[level])
                h = h.index_copy(0, ids, sub)
            if summaries is not None:
                h = h + _group_summary(summaries[0][k], h, summaries[1], summaries[2])
        return h, e


def _group_summary(summary: nn.Module, h: Tensor, group: Tensor | None, sizes: Tensor | None) -> Tensor:
    """Per node (N, D), `summary` of the mean latent of its group; group: each node's group from 0
    and sizes (G,): each group's node count (None, None: every node in one group)."""
    if group is None:
        return summary(h.mean(0, keepdim=True)).expand_as(h)
    means = torch.zeros(len(sizes), h.shape[1], dtype=h.dtype, device=h.device).index_add_(0, group, h)
    return summary(means / sizes.to(h.dtype)[:, None]).index_select(0, group)

"""Garment rest state: the static, per-mesh quantities the physics and the network read.

A `Garment` is one template mesh in its rest state (on the canonical body). A `GarmentBatch`
packs several garments of different sizes into one set of tensors (vertices of garment g at rows
`vert_offsets[g]:vert_offsets[g + 1]`, indices shifted accordingly), so every physics function
runs on one garment or many with the same code. Positions x are state and live elsewhere.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields, replace

import numpy as np
import torch
from torch import Tensor

from physdrape.geometry import topology
from physdrape.geometry.mesh import check_mesh
from physdrape.geometry.normals import vertex_normals  # noqa: F401  (re-exported beside the garment types)
from physdrape.tensor_memo import IdentityMemo, KeyedMemo


def rest_frames(rest: Tensor, faces: Tensor) -> tuple[Tensor, Tensor]:
    """Per-face inverse rest matrices Dm⁻¹ and rest areas.

    Dm holds the two edge vectors (x1 − x0, x2 − x0) of the rest triangle in an orthonormal 2-D
    frame of that triangle (first axis along x1 − x0).

    Args:
        rest: rest positions [m], shape (V, 3).
        faces: shape (F, 3) int64.
    Returns:
        rest_inv: Dm⁻¹ [1/m], shape (F, 2, 2); rest_area: [m²], shape (F,).
    """
    x0, x1, x2 = rest[faces[:, 0]], rest[faces[:, 1]], rest[faces[:, 2]]
    e1, e2 = x1 - x0, x2 - x0
    normal = torch.linalg.cross(e1, e2)
    double_area = normal.norm(dim=-1)
    len1 = e1.norm(dim=-1)
    u = e1 / len1[:, None]
    v = torch.linalg.cross(normal / double_area[:, None], u)
    dm = torch.stack(
        [torch.stack([len1, (e2 * u).sum(-1)], -1), torch.stack([torch.zeros_like(len1), (e2 * v).sum(-1)], -1)],
        dim=-2,
    )
    return torch.linalg.inv(dm), 0.5 * double_area


@dataclass(frozen=True)
class Garment:
    """One garment template in its rest state (numpy-free, in one dtype).

    Attributes:
        rest: rest vertex positions [m], shape (V, 3).
        faces: triangles, shape (F, 3) int64.
        edges: undirected edges (i < j), shape (E, 2) int64.
        hinges: interior hinges [v0, v1 shared edge, v2, v3 opposite], shape (H, 4) int64.
        rest_inv: Dm⁻¹ per face [1/m], shape (F, 2, 2).
        rest_area: rest face areas [m²], shape (F,).
        boundary_loops: the garment's openings, each a loop of vertex indices.
        name: a label for messages.
    """

    rest: Tensor
    faces: Tensor
    edges: Tensor
    hinges: Tensor
    rest_inv: Tensor
    rest_area: Tensor
    boundary_loops: tuple[Tensor, ...]
    name: str = "garment"

    @staticmethod
    def from_mesh(verts, faces, *, name: str = "garment", dtype: torch.dtype = torch.float64) -> "Garment":
        """Validate a template mesh (see `check_mesh`) and compute its rest-state quantities.

        Args:
            verts: rest positions [m], array-like of shape (V, 3).
            faces: triangles, array-like of shape (F, 3).
            dtype: floating dtype of the returned tensors.
        """
        verts_np = np.asarray(verts.detach().cpu() if isinstance(verts, Tensor) else verts, dtype=np.float64)
        faces_np = np.asarray(faces.detach().cpu() if isinstance(faces, Tensor) else faces)
        check_mesh(verts_np, faces_np, name=name)
        faces_np = faces_np.astype(np.int64)
        rest64 = torch.from_numpy(verts_np)
        faces_t = torch.from_numpy(faces_np)
        rest_inv, rest_area = rest_frames(rest64, faces_t)
        return Garment(
            rest=rest64.to(dtype),
            faces=faces_t,
            edges=torch.from_numpy(topology.undirected_edges(faces_np)),
            hinges=torch.from_numpy(topology.interior_hinges(faces_np)),
            rest_inv=rest_inv.to(dtype),
            rest_area=rest_area.to(dtype),
            boundary_loops=tuple(torch.from_numpy(loop) for loop in topology.boundary_loops(faces_np)),
            name=name,
        )

    @property
    def num_verts(self) -> int:
        return self.rest.shape[0]

    @property
    def num_faces(self) -> int:
        return self.faces.shape[0]

    @property
    def device(self) -> torch.device:
        return self.rest.device

    def to(self, dtype: torch.dtype | None = None, *, device: torch.device | str | None = None) -> "Garment":
        """The same garment with floating tensors in `dtype` (None: kept) and every tensor on
        `device` (None: kept)."""
        def move(t: Tensor) -> Tensor:
            return t.to(device=device, dtype=dtype if t.is_floating_point() else None)

        return replace(self, rest=move(self.rest), faces=move(self.faces), edges=move(self.edges),
                       hinges=move(self.hinges), rest_inv=move(self.rest_inv), rest_area=move(self.rest_area),
                       boundary_loops=tuple(move(loop) for loop in self.boundary_loops))


@dataclass(frozen=True)
class GraphLevels:
    """A garment batch's message-passing graphs: level 0 the mesh edges, level l > 0 the edges of
    the l-th coarse graph, which joins a subset of the vertices about 2^l mesh edges apart.

    Attributes:
        edge_index: (2, E') all levels' directed edges in batch vertex ids, grouped by level
            (level 0 first: the mesh's `edge_index`), row 0 = sender.
        level: (E',) the level of each edge.
        nodes: per level, the batch vertex ids it joins (sorted; level 0: all vertices).
        local_edge_index: per level, its edges in positions of `nodes[level]`.
    """

    edge_index: Tensor
    level: Tensor
    nodes: tuple[Tensor, ...]
    local_edge_index: tuple[Tensor, ...]
    _parts: dict = field(default_factory=dict, compare=False, repr=False)  # `part`'s results, by (start, stop)

    @property
    def edge_counts(self) -> list[int]:
        return [int(e.shape[1]) for e in self.local_edge_index]

    def part(self, start: int, stop: int) -> tuple[GraphLevels, list[Tensor]]:
        """The graphs of the batch vertices [start, stop) alone (whole garments: no edge leaves
        them), their vertex ids shifted to start at 0, and per level the positions of their edges
        among the level's edges (for cutting per-edge values to match); formed once per piece."""
        if (start, stop) not in self._parts:
            self._parts[start, stop] = self._part(start, stop)
        return self._parts[start, stop]

    def _part(self, start: int, stop: int) -> tuple[GraphLevels, list[Tensor]]:
        nodes, local, chosen = [], [], []
        for ids, edges in zip(self.nodes, self.local_edge_index):
            lo, hi = (int(k) for k in torch.searchsorted(ids, torch.tensor([start, stop], device=ids.device)))
            picked = torch.nonzero((edges[0] >= lo) & (edges[0] < hi))[:, 0]
            nodes.append(ids[lo:hi] - start)
            local.append(edges[:, picked] - lo)
            chosen.append(picked)
        sizes = [int(k.shape[0]) for k in chosen]
        level = torch.cat([torch.full((n,), l, dtype=torch.int64, device=self.level.device) for l, n in enumerate(sizes)])
        edge_index = torch.cat([ids[e] for ids, e in zip(nodes, local)], dim=1)
        return GraphLevels(edge_index, level, tuple(nodes), tuple(local)), chosen


@dataclass(frozen=True)
class GarmentBatch:
    """Several garments packed into one mesh with per-garment offsets.

    Attributes (Σ over the garments of the batch):
        rest: (ΣV, 3) [m]; faces: (ΣF, 3); edges: (ΣE, 2); hinges: (ΣH, 4); all indices global.
        edge_index: both directions of every edge, (2, 2ΣE), row 0 = sender.
        rest_inv: (ΣF, 2, 2) [1/m]; rest_area: (ΣF,) [m²].
        vert_garment, face_garment, hinge_garment: owning garment of each element, int64.
        vert_offsets: (G + 1,) first vertex of each garment, last entry ΣV.
        garments: the unpacked garments, in order.
    All tensors live on one device, the garments' (`to` moves them).
    """

    rest: Tensor
    faces: Tensor
    edges: Tensor
    edge_index: Tensor
    hinges: Tensor
    rest_inv: Tensor
    rest_area: Tensor
    vert_garment: Tensor
    face_garment: Tensor
    hinge_garment: Tensor
    vert_offsets: Tensor
    garments: tuple[Garment, ...]

    @staticmethod
    def pack(garments) -> "GarmentBatch":
        """Pack garments (a sequence of `Garment`, or a single one) into one batch; the same
        garments (by identity) in the same order give the same batch object again."""
        if isinstance(garments, Garment):
            garments = [garments]
        garments = tuple(garments)
        if not garments:
            raise ValueError("GarmentBatch.pack needs at least one garment")
        return _PACKED.get(garments, None, lambda: GarmentBatch._pack(garments))

    @staticmethod
    def _pack(garments: tuple[Garment, ...]) -> GarmentBatch:
        dtypes = {g.rest.dtype for g in garments}
        if len(dtypes) > 1:
            raise ValueError(f"garments of one batch must share a dtype, got {sorted(map(str, dtypes))}")
        devices = {g.device for g in garments}
        if len(devices) > 1:
            raise ValueError(f"garments of one batch must be on one device, got {sorted(map(str, devices))}: "
                             "move them with Garment.to(device=...)")
        device = garments[0].device
        counts = torch.tensor([g.num_verts for g in garments], device=device)
        offsets = torch.cat([torch.zeros(1, dtype=torch.int64, device=device), counts.cumsum(0)])

        def cat_indices(name: str) -> Tensor:
            return torch.cat([getattr(g, name) + offsets[k] for k, g in enumerate(garments)])

        def owner(name: str) -> Tensor:
            sizes = torch.tensor([getattr(g, name).shape[0] for g in garments], device=device)
            return torch.repeat_interleave(torch.arange(len(garments), device=device), sizes)

        edges = cat_indices("edges")
        return GarmentBatch(
            rest=torch.cat([g.rest for g in garments]),
            faces=cat_indices("faces"),
            edges=edges,
            edge_index=torch.cat([edges.T, edges.flip(1).T], dim=1),
            hinges=cat_indices("hinges"),
            rest_inv=torch.cat([g.rest_inv for g in garments]),
            rest_area=torch.cat([g.rest_area for g in garments]),
            vert_garment=owner("rest"),
            face_garment=owner("faces"),
            hinge_garment=owner("hinges"),
            vert_offsets=offsets,
            garments=garments,
        )

    @property
    def num_garments(self) -> int:
        return len(self.garments)

    @property
    def num_verts(self) -> int:
        return self.rest.shape[0]

    @property
    def dtype(self) -> torch.dtype:
        return self.rest.dtype

    @property
    def device(self) -> torch.device:
        return self.rest.device

    def graph_levels(self, levels: int) -> GraphLevels:
        """The mesh graph (level 0) and `levels` coarser graphs over subsets of its vertices
        (`topology.coarse_graphs`, per garment), both edge directions, for hierarchical message
        passing. A garment whose hierarchy ends early contributes nothing to the deeper levels.
        The coarsening runs on the host (numpy, kept per topology by `topology.coarse_graphs`); the
        graphs are on the batch's device."""
        if levels < 0:
            raise ValueError(f"levels must be ≥ 0, got {levels}")
        keys = [_topology_key(garment) for garment in self.garments]
        return _GRAPH_LEVELS.get((tuple(keys), levels, str(self.device)), lambda: self._graph_levels(levels))

    def _graph_levels(self, levels: int) -> GraphLevels:
        device = self.device
        per_level: list[list[Tensor]] = [[] for _ in range(levels)]
        offsets = self.vert_offsets.tolist()
        for g, garment in enumerate(self.garments):
            coarse = topology.coarse_graphs(garment.edges.cpu().numpy(), garment.num_verts, levels)
            for l, edges in enumerate(coarse):
                per_level[l].append(torch.from_numpy(topology.bidirectional_edges(edges)) + offsets[g])
        edge_index, nodes, local = [self.edge_index], [torch.arange(self.num_verts, device=device)], [self.edge_index]
        for parts in per_level:
            both = (torch.cat(parts, dim=1) if parts else torch.zeros(2, 0, dtype=torch.int64)).to(device)
            ids = torch.unique(both)
            edge_index.append(both)
            nodes.append(ids)
            local.append(torch.searchsorted(ids, both))
        level = torch.cat([torch.full((e.shape[1],), l, dtype=torch.int64, device=device)
                           for l, e in enumerate(edge_index)])
        return GraphLevels(torch.cat(edge_index, dim=1), level, tuple(nodes), tuple(local))

    def split(self, values: Tensor) -> list[Tensor]:
        """Split per-vertex values (..., ΣV, C) into one tensor per garment."""
        sizes = (self.vert_offsets[1:] - self.vert_offsets[:-1]).tolist()
        return list(torch.split(values, sizes, dim=-2))

    def to(self, dtype: torch.dtype | None = None, *, device: torch.device | str | None = None) -> "GarmentBatch":
        """The same batch with floating tensors in `dtype` (None: kept) and every tensor, the
        unpacked garments' included, on `device` (None: kept); this batch itself where nothing changes."""
        if (dtype is None or dtype == self.dtype) and (device is None or torch.device(device) == self.device):
            return self
        changes = {f.name: value.to(device=device, dtype=dtype if value.is_floating_point() else None)
                   for f in fields(self) if isinstance(value := getattr(self, f.name), Tensor)}
        return replace(self, garments=tuple(g.to(dtype, device=device) for g in self.garments), **changes)


#: Batches by their garments (a drape of the same garments packs them once).
_PACKED = IdentityMemo(16)
#: A batch's graph levels by its garments' topologies (a drape of the same garments reuses them).
_GRAPH_LEVELS = KeyedMemo(16)


def _topology_key(garment: Garment) -> bytes:
    """A digest of a garment's edges and vertex count."""
    return topology.digest(garment.edges.cpu().numpy()) + bytes(str(garment.num_verts), "ascii")

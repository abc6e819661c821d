"""Kinematic initialisation of a garment on a shaped, posed body (paper Eq. 5, DESIGN Sec. 3.2).

Every garment vertex borrows the body's shape displacement and skinning transforms through a
fixed, sparse transfer matrix ``W`` (garment vertices x body vertices), fitted once per garment
template on the canonical body:

1. **Diffusion from the surface**: the ``k`` nearest body triangles of each garment vertex (exact
   point-triangle distances; the closest one always included) each contribute their closest point,
   i.e. its three vertices with the point's barycentrics, with a Gaussian weight
   ``exp(-(d^2 - d_min^2) / (2 sigma^2))``, ``sigma = max(d_min, mean body edge length)``: loose
   parts far from the body blend over a wider patch.
2. **Smoothing over the garment graph**: ``W <- (1 - a) W + a * mean over mesh neighbours(W)``
   for a few iterations, so neighbouring garment vertices carry similar weights (a bare nearest
   vertex tears loose parts, e.g. a sleeve whose vertices snap to torso and arm).
3. Influences below ``prune_below`` are dropped, rows renormalised to sum to 1 (all > 0).

Then, for a batch of bodies (``BodyState``), with ``X_temp`` the template:

    dX_shape = W (rest_verts - canonical_verts)        (shape displacement, rest pose)
    T_i      = sum_j W_ij vertex_transforms_j          (LBS is linear in the weights)
    X_init   = T_i[:3, :3] (X_temp + dX_shape)_i + T_i[:3, 3]

``fit`` costs a KD-tree plus a few sparse products (once per garment); ``apply`` is one sparse
(CSR) x dense product plus an einsum, differentiable w.r.t. the body tensors. The weights are kept
exactly (no fixed number of influences): truncating smoothed weights to a top-K tears the
garment between two equidistant limbs.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
import torch
from scipy.spatial import cKDTree
from torch import Tensor

from physdrape.geometry.closest_point import closest_point_on_triangle
from physdrape.geometry.proximity import BodySurface, SignMethod
from physdrape.geometry.strain_limit import limit_edge_stretch
from physdrape.geometry.topology import undirected_edges
from physdrape.physics.contact import DEFAULT_MARGIN

__all__ = ["BodySearch", "SkinningTransfer"]


def _as_float_array(name: str, value, ndim_last: int = 3) -> np.ndarray:
    arr = value.detach().cpu().numpy() if isinstance(value, Tensor) else np.asarray(value)
    if arr.ndim != 2 or arr.shape[1] != ndim_last or not np.issubdtype(arr.dtype, np.floating):
        raise ValueError(f"{name} must be a float array of shape (N, {ndim_last}), got {arr.shape} {arr.dtype}")
    if not np.isfinite(arr).all():
        raise ValueError(f"{name} contains NaN/inf")
    return arr.astype(np.float64)


def _as_faces(name: str, value, num_verts: int) -> np.ndarray:
    arr = value.detach().cpu().numpy() if isinstance(value, Tensor) else np.asarray(value)
    if arr.ndim != 2 or arr.shape[1] != 3 or not np.issubdtype(arr.dtype, np.integer) or len(arr) == 0:
        raise ValueError(f"{name} must be an integer array of shape (F, 3), got {arr.shape} {arr.dtype}")
    if arr.min() < 0 or arr.max() >= num_verts:
        bad = arr.min() if arr.min() < 0 else arr.max()
        raise ValueError(f"indices in {name} must be in [0, {num_verts}) (got {bad})")
    return arr.astype(np.int64)


def _garment_smoother(faces: np.ndarray, num_verts: int) -> sp.csr_matrix:
    """Row-stochastic mean-over-neighbours operator of the garment edge graph, (V, V).

    Vertices without an edge keep their own value (a self loop).
    """
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    e = np.concatenate([e, e[:, ::-1]])
    adj = sp.coo_matrix((np.ones(len(e)), (e[:, 0], e[:, 1])), shape=(num_verts, num_verts)).tocsr()
    adj.data[:] = 1.0  # duplicate edges count once
    deg = np.asarray(adj.sum(1)).ravel()
    lonely = deg == 0
    adj = adj + sp.diags(lonely.astype(np.float64))
    deg[lonely] = 1.0
    return sp.diags(1.0 / deg) @ adj


#: The fields of `SkinningTransfer` that set X_init's strain limiting (what a pipeline may
#: override, `pipeline.DrapePipeline`, and what an instance cache records, `train.instances`).
LIMIT_FIELDS = ("max_stretch", "min_stretch", "limit_sweeps", "limit_momentum", "contact_margin")


#: Bound of the first, local strain-limiting stage (plain Jacobi, no contact): the skin itself
#: stretches severalfold at the armpit under raised arms, and momentum sweeps handle such spikes
#: badly.
LOCAL_STRETCH_BOUND = 1.5


@dataclass(frozen=True, eq=False)
class BodySearch:
    """What `SkinningTransfer.fit` searches on a canonical body, built once per body and reused
    for every template fitted on it (`of`): the body as float64 / int64 arrays, its triangles
    (Fb, 3, 3), a k-d tree of their centroids, its BVH (only closest faces are asked: the
    pseudo-normal sign) and its mean edge length [m]."""

    verts: np.ndarray
    faces: np.ndarray
    triangles: np.ndarray
    centroids: cKDTree
    surface: BodySurface
    edge_length: float

    @classmethod
    def of(cls, canonical_verts, body_faces) -> BodySearch:
        """The search structures of a canonical body, rest pose [m] (Vb, 3), triangles (Fb, 3) int."""
        verts = _as_float_array("canonical_verts", canonical_verts)
        faces = _as_faces("body_faces", body_faces, len(verts))
        tri = verts[faces]
        surface = BodySurface(torch.from_numpy(verts), torch.from_numpy(faces), sign_method=SignMethod.PSEUDO_NORMAL)
        edge_length = float(np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=-1).mean())
        return cls(verts, faces, tri, cKDTree(tri.mean(1)), surface, edge_length)


@dataclass(frozen=True)
class SkinningTransfer:
    """Sparse body-to-garment transfer weights, fitted once per garment template.

    Attributes:
        weights: transfer matrix W, sparse CSR, shape (V, Vb); entries > 0, rows sum to 1.
        canonical_verts: canonical body the template was authored on [m], shape (Vb, 3).
        template_verts: garment template [m], shape (V, 3).
        edges: the template's undirected edges, shape (E, 2) int64.
        max_stretch: bound on edge length / rest length that X_init's edges are pulled back
            toward after skinning, for `limit_sweeps` sweeps (see
            `physdrape.geometry.strain_limit`; where the body holds the garment out, some edges
            stay above it); None leaves the skinned positions as they are.
        min_stretch: bound on edge length / rest length that X_init's compressed edges are
            pushed back toward in the same sweeps (< 1), or None (compression left as skinned).
        limit_sweeps: strain-limiting sweeps (momentum-accelerated Jacobi edge projection).
        limit_momentum: heavy-ball momentum of those sweeps (0 = plain Jacobi).
        contact_margin: during strain limiting, vertices are held at least this far outside the
            posed body [m] (when `apply` is given a body with posed verts); None = no contact.

    Why a tight bound (1.02) with contact: skinning copies the body's own growth onto the
    garment, so on a taller or wider body than the canonical one the garment is stretched
    everywhere, while the static equilibrium lets it ride up and hug the body instead, barely
    stretched. Pulling the edges back toward 1.02 x rest with the body held out brings X_init
    close to that (the pull acts on stretched edges only): the model and its solver start from
    a nearly unstretched garment that is still outside the body (the "X_init" and "Skinned"
    rows of `results/eval.md` compare the two starts).

    Why a lower bound (0.9): skinning also compresses the garment where the skin folds (under a
    bent elbow, at the armpit, over the belly of a heavier body), and that compression is much
    of X_init's strain energy, which the network and the solver's first steps must otherwise
    undo. Pushing edges shorter than 0.9 x rest apart in the same sweeps (with the body
    held out) takes X_init's E_total on the held-out set from 1.607 to 1.438 times the teacher
    drapes', the network's drape (a network trained without the bound) from 1.219 to 1.194 and
    the solver alone's at T = 3 from 1.131 to 1.087; 0.85 and 0.95 do less for the network
    (`results/x_init_bounds_skinned_model.md`, `bench/x_init_bounds.py`).
    """

    weights: Tensor
    canonical_verts: Tensor
    template_verts: Tensor
    edges: Tensor
    max_stretch: float | None = 1.02
    min_stretch: float | None = 0.9
    limit_sweeps: int = 60
    limit_momentum: float = 0.9
    contact_margin: float | None = DEFAULT_MARGIN

    @property
    def num_verts(self) -> int:
        """Number of garment vertices V."""
        return self.weights.shape[0]

    @property
    def num_body_verts(self) -> int:
        """Number of body vertices Vb."""
        return self.canonical_verts.shape[0]

    @classmethod
    def fit(
        cls,
        canonical_verts: Tensor,
        body_faces: Tensor,
        garment_verts: Tensor,
        garment_faces: Tensor,
        *,
        k: int = 8,
        smoothing_iterations: int = 10,
        smoothing_strength: float = 0.5,
        prune_below: float = 1e-4,
        num_candidates: int | None = None,
        max_stretch: float | None = 1.02,
        search: BodySearch | None = None,
    ) -> SkinningTransfer:
        """Fit transfer weights of a garment template on the canonical body.

        Args:
            canonical_verts: canonical body, rest pose [m], shape (Vb, 3).
            body_faces: body triangles, shape (Fb, 3) int.
            garment_verts: garment template on that body [m], shape (V, 3).
            garment_faces: garment triangles, shape (F, 3) int (its edges define the smoothing graph).
            k: number of nearest body triangles each garment vertex draws from.
            smoothing_iterations: Laplacian smoothing passes over the garment graph (0 = none).
            smoothing_strength: step a in (0, 1] of each pass.
            prune_below: influences lighter than this are dropped after smoothing (rows are then
                renormalised); 0 keeps every influence.
            num_candidates: triangles pre-selected by centroid distance before the exact test
                (default max(4k, 32)).
            max_stretch: bound on the edge stretch of X_init (strain limiting after skinning;
                > 1), or None for plain skinning.
            search: `BodySearch.of(canonical_verts, body_faces)`, made once by a caller that fits
                many templates on the same body; None makes it here.

        Returns:
            The fitted ``SkinningTransfer`` (tensors in the dtype of ``canonical_verts`` when it is
            a floating tensor, else float64).
        """
        if k < 1 or smoothing_iterations < 0 or not 0 <= prune_below < 0.5:
            raise ValueError(f"need k >= 1, smoothing_iterations >= 0, 0 <= prune_below < 0.5 "
                             f"(got {k}, {smoothing_iterations}, {prune_below})")
        if not 0.0 < smoothing_strength <= 1.0:
            raise ValueError(f"smoothing_strength must be in (0, 1], got {smoothing_strength}")
        if max_stretch is not None and not max_stretch > 1.0:
            raise ValueError(f"max_stretch must be > 1 or None, got {max_stretch}")
        dtype = canonical_verts.dtype if isinstance(canonical_verts, Tensor) and canonical_verts.is_floating_point() \
            else torch.float64
        if search is None:
            search = BodySearch.of(canonical_verts, body_faces)
        elif search.verts.shape != tuple(np.shape(canonical_verts)) or search.faces.shape != tuple(np.shape(body_faces)):
            raise ValueError(f"search is of a body with {search.verts.shape[0]} vertices and {search.faces.shape[0]} "
                             f"faces, not this one ({np.shape(canonical_verts)}, {np.shape(body_faces)}): pass "
                             "BodySearch.of(canonical_verts, body_faces)")
        vb, fb, tri = search.verts, search.faces, search.triangles
        vg = _as_float_array("garment_verts", garment_verts)
        fg = _as_faces("garment_faces", garment_faces, len(vg))
        num_body, num_garment, num_faces = len(vb), len(vg), len(fb)

        # 1. k nearest triangles (exact distances among centroid-preselected candidates).
        k = min(k, num_faces)
        num_cand = min(num_faces, num_candidates or max(4 * k, 32))
        _, cand = search.centroids.query(vg, k=num_cand)
        cand = cand.reshape(num_garment, num_cand)
        # Make sure the true closest triangle is a candidate: BVH query on the canonical body.
        vg_t = torch.from_numpy(vg)
        closest = search.surface.query(vg_t).face
        cand = np.concatenate([closest.numpy()[:, None], cand], 1)
        tri_t = torch.from_numpy(tri)[torch.from_numpy(cand)]  # (V, C, 3, 3)
        p, bary = closest_point_on_triangle(vg_t[:, None], tri_t[..., 0, :], tri_t[..., 1, :], tri_t[..., 2, :])
        dist = (vg_t[:, None] - p).norm(dim=-1)
        dist[:, 1:][torch.from_numpy(cand[:, 1:] == cand[:, :1])] = torch.inf  # duplicates of the closest
        dist, order = torch.topk(dist, k, dim=1, largest=False)
        faces_k = np.take_along_axis(cand, order.numpy(), 1)  # (V, k)
        bary = bary.gather(1, order[..., None].expand(-1, -1, 3))  # (V, k, 3)

        # Gaussian weights relative to the closest distance.
        d0 = dist[:, :1]
        sigma = d0.clamp_min(search.edge_length)
        w = torch.exp(-(dist.square() - d0.square()) / (2 * sigma.square()))
        w = torch.where(torch.isfinite(dist), w, torch.zeros_like(w))
        w = (w[..., None] * bary).reshape(num_garment, -1)  # (V, 3k)
        rows = np.repeat(np.arange(num_garment), 3 * k)
        cols = fb[faces_k].reshape(-1)
        mat = sp.csr_matrix((w.numpy().ravel(), (rows, cols)), shape=(num_garment, num_body))
        mat = sp.diags(1.0 / np.asarray(mat.sum(1)).ravel()) @ mat

        # 2. Smoothing over the garment graph.
        if smoothing_iterations:
            # each pass W ← (1 − a) W + a S W, as one sparse product with (1 − a) I + a S (one
            # pass over W's entries a pass, not a product, two scalings and a sum)
            step = (sp.identity(num_garment, format="csr") * (1.0 - smoothing_strength)
                    + _garment_smoother(fg, num_garment) * smoothing_strength).tocsr()
            for _ in range(smoothing_iterations):
                mat = step @ mat
        mat = mat.tocsr()
        mat.eliminate_zeros()

        # 3. Drop negligible influences, renormalise.
        if prune_below > 0:
            mat.data[mat.data < prune_below] = 0.0
            mat.eliminate_zeros()
        mat = sp.diags(1.0 / np.asarray(mat.sum(1)).ravel()) @ mat
        mat = mat.tocsr()
        mat.sort_indices()
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
            weights = torch.sparse_csr_tensor(
                torch.from_numpy(mat.indptr.astype(np.int64)), torch.from_numpy(mat.indices.astype(np.int64)),
                torch.from_numpy(mat.data).to(dtype), (num_garment, num_body), check_invariants=False,
            )
        return cls(weights=weights, canonical_verts=torch.from_numpy(vb).to(dtype),
                   template_verts=torch.from_numpy(vg).to(dtype),
                   edges=torch.from_numpy(undirected_edges(fg)), max_stretch=max_stretch)

    def to(self, device: torch.device | str) -> SkinningTransfer:
        """This transfer with its tensors on `device` (`apply` then skins and limits there)."""
        return replace(self, weights=self.weights.to(device), canonical_verts=self.canonical_verts.to(device),
                       template_verts=self.template_verts.to(device), edges=self.edges.to(device))

    def weight_matrix(self) -> Tensor:
        """The transfer weights as a dense matrix, shape (V, Vb) (for inspection and tests)."""
        return self.weights.to_dense()

    def influences(self) -> tuple[Tensor, Tensor]:
        """Padded per-row view: body vertex index and weight, each shape (V, K), K = max row nnz.

        Padding has index 0 and weight 0.
        """
        crow, col, val = self.weights.crow_indices(), self.weights.col_indices(), self.weights.values()
        counts = crow[1:] - crow[:-1]
        width = int(counts.max())
        row = torch.arange(self.num_verts).repeat_interleave(counts)
        slot = torch.arange(len(col)) - crow[:-1].repeat_interleave(counts)
        index = torch.zeros(self.num_verts, width, dtype=torch.int64).index_put_((row, slot), col)
        weight = torch.zeros(self.num_verts, width, dtype=val.dtype).index_put_((row, slot), val)
        return index, weight

    def _blend(self, per_body_vertex: Tensor) -> Tensor:
        """W @ values per batch element: (B, Vb, C) -> (B, V, C), in the values' dtype."""
        with warnings.catch_warnings():
            warnings.filterwarnings("ignore", message="Sparse CSR tensor support is in beta")
            weights = self.weights.to(device=per_body_vertex.device, dtype=per_body_vertex.dtype)
        batch, num_body, width = per_body_vertex.shape
        blended = weights @ per_body_vertex.permute(1, 0, 2).reshape(num_body, batch * width)
        return blended.reshape(self.num_verts, batch, width).permute(1, 0, 2)

    def blended_transforms(self, body) -> Tensor:
        """T_i = sum_j W_ij T_j: the body's skinning transforms blended per garment vertex, top
        three rows, shape (B, V, 3, 4) (X_init = T_i[:3, :3] x_rest + T_i[:3, 3])."""
        transforms = body.vertex_transforms
        batch, num_body = transforms.shape[:2]
        return self._blend(transforms[..., :3, :].reshape(batch, num_body, 12)).reshape(batch, self.num_verts, 3, 4)

    def limit_stretch(self, x: Tensor, garment_verts: Tensor | None = None, *, body: BodySurface | None = None) -> Tensor:
        """Bound the edge stretch of garment positions x (..., V, 3) by `max_stretch` (and, in
        the stage with the body, their compression by `min_stretch`) relative to the template
        (the garment's rest state in the physics), holding the vertices out of `body` (one body
        per leading index) when it is given and `contact_margin` is set; identity when
        `max_stretch` is None."""
        if self.max_stretch is None:
            return x
        x_temp = (self.template_verts if garment_verts is None else garment_verts).to(x.dtype)
        rest_lengths = (x_temp[..., self.edges[:, 1], :] - x_temp[..., self.edges[:, 0], :]).norm(dim=-1)
        if self.max_stretch >= LOCAL_STRETCH_BOUND:
            return limit_edge_stretch(x, self.edges, rest_lengths, max_stretch=self.max_stretch)
        # 1. The local skinning artefacts, by plain Jacobi. 2. The global pull back to
        # max_stretch, with momentum and the body held out. 3. Stage 1 again: stage 2 stops after
        # limit_sweeps and can leave a few edges it was still pulling on above the local bound.
        x = limit_edge_stretch(x, self.edges, rest_lengths, max_stretch=LOCAL_STRETCH_BOUND)
        contact = {} if body is None or self.contact_margin is None else {"body": body, "margin": self.contact_margin}
        x = limit_edge_stretch(x, self.edges, rest_lengths, max_stretch=self.max_stretch, min_stretch=self.min_stretch,
                               iterations=self.limit_sweeps, momentum=self.limit_momentum, **contact)
        return limit_edge_stretch(x, self.edges, rest_lengths, max_stretch=LOCAL_STRETCH_BOUND)

    def shaped_rest(self, body) -> Tensor:
        """X_temp + dX_shape: the template moved with the body's shape, rest pose [m], shape
        (B, V, 3) in the dtype of ``body.rest_verts`` (the rest shape of a garment sized to fit)."""
        rest = body.rest_verts
        canonical = self.canonical_verts.to(device=rest.device, dtype=rest.dtype)
        return self.template_verts.to(device=rest.device, dtype=rest.dtype) + self._blend(rest - canonical)

    def apply(self, body, garment_verts: Tensor | None = None, *, rest_verts: Tensor | None = None,
              surface: BodySurface | None = None) -> Tensor:
        """X_init = LBS(X_temp + dX_shape, pose) on a batch of bodies (paper Eq. 5).

        Args:
            body: a ``BodyState`` (uses ``rest_verts`` (B, Vb, 3) and ``vertex_transforms``
                (B, Vb, 4, 4)) of the body model the weights were fitted on.
            garment_verts: garment in the canonical pose on the canonical body [m], shape (V, 3)
                or (B, V, 3); default the fitted template.
            rest_verts: the garment's own rest shape on these bodies in their rest pose [m],
                (V, 3) or (B, V, 3) (a garment sized to fit): skinned instead of
                X_temp + dX_shape, and the reference of the stretch limit.
            surface: the posed bodies of ``body`` as a `BodySurface` (any dtype: it is queried in
                its own), if the caller holds one (else it is built here for the strain limiting's
                contact).

        Returns:
            X_init: garment positions [m], shape (B, V, 3), in the dtype of ``body.rest_verts``;
            differentiable w.r.t. the body tensors and ``garment_verts`` (through the skinning;
            the strain limiting's corrections count as a fixed displacement).
        """
        rest, transforms = body.rest_verts, body.vertex_transforms
        if rest.ndim != 3 or rest.shape[1:] != (self.num_body_verts, 3):
            raise ValueError(f"body.rest_verts must have shape (B, {self.num_body_verts}, 3) (the body the "
                             f"transfer was fitted on), got {tuple(rest.shape)}")
        if transforms.shape != (*rest.shape[:2], 4, 4):
            raise ValueError(f"body.vertex_transforms must have shape {(*rest.shape[:2], 4, 4)}, "
                             f"got {tuple(transforms.shape)}")
        dtype, device = rest.dtype, rest.device
        x_temp = self.template_verts if garment_verts is None else garment_verts
        if x_temp.shape[-2:] != (self.num_verts, 3) or x_temp.ndim not in (2, 3):
            raise ValueError(f"garment_verts must have shape ({self.num_verts}, 3) or (B, {self.num_verts}, 3), "
                             f"got {tuple(x_temp.shape)}")
        if garment_verts is not None and garment_verts.dtype != dtype:
            raise TypeError(f"garment_verts have dtype {garment_verts.dtype}, the body {dtype}; convert explicitly")
        x_temp = x_temp.to(device=device, dtype=dtype)
        canonical = self.canonical_verts.to(device=device, dtype=dtype)

        # One sparse product blends the shape displacement and the top 3 rows of the transforms.
        batch, num_body = rest.shape[:2]
        blended = self._blend(torch.cat([rest - canonical, transforms[..., :3, :].reshape(batch, num_body, 12)], -1))
        x_rest = x_temp + blended[..., :3]
        if rest_verts is not None:
            if rest_verts.shape[-2:] != (self.num_verts, 3):
                raise ValueError(f"rest_verts must have shape ({self.num_verts}, 3) or (B, {self.num_verts}, 3), "
                                 f"got {tuple(rest_verts.shape)}")
            x_rest = x_temp = rest_verts.to(device=device, dtype=dtype).expand_as(x_rest)
        affine = blended[..., 3:].reshape(batch, self.num_verts, 3, 4)
        x = torch.einsum("bvij,bvj->bvi", affine[..., :3], x_rest) + affine[..., 3]
        return self.limit_stretch(x, x_temp, body=_posed_surface(body, dtype) if surface is None else surface)


def _posed_surface(body, dtype: torch.dtype) -> BodySurface | None:
    """The posed body surface of a ``BodyState`` (for contact during strain limiting), or None
    when the state carries no posed vertices or faces."""
    verts, faces = getattr(body, "verts", None), getattr(body, "faces", None)
    if not isinstance(verts, Tensor) or verts.ndim != 3 or verts.shape[0] == 0 or faces is None or len(faces) == 0:
        return None
    return BodySurface(verts.detach().to(dtype), faces)

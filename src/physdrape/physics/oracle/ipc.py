"""The oracle's IPC contact: the barrier of PyPI ``ipctk`` between each garment and its posed
body (a static obstacle), with continuous collision detection for the step length."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
import torch
from torch import Tensor

from physdrape.physics.cloth import Cloth

#: Default IPC barrier stiffness κ and activation distance d̂ [m] (DESIGN.md Sec. 5).
DEFAULT_BARRIER_STIFFNESS = 1e5
DEFAULT_DHAT = 3e-3


def _import_ipctk():
    try:
        import ipctk  # optional dependency
    except ImportError:
        raise ImportError("contact='ipc' needs the ipctk package (IPC Toolkit): pip install ipctk; "
                          "or use contact='penalty'") from None
    return ipctk


class _IPCContact:
    """IPC barrier between each garment and its posed body (static obstacle), one mesh per garment.

    Positions are packed (ΣV, 3) numpy arrays [m]; vert_offsets (G + 1,) delimit the garments.
    """

    def __init__(self, x: Tensor, cloth: Cloth, bodies, body_index: Tensor, vert_offsets: list[int], *,
                 stiffness: float, dhat: float, self_contact: bool) -> None:
        ipctk = _import_ipctk()
        self.ipctk, self.stiffness, self.dhat = ipctk, stiffness, dhat
        self.bodies = bodies
        self.offsets = vert_offsets
        body_verts = bodies.verts.detach().to(torch.float64).cpu().numpy()
        body_faces = bodies.faces.cpu().numpy().astype(np.int32)
        faces = cloth.faces.cpu().numpy()
        self.meshes, self.body_pos = [], []
        for g in range(len(vert_offsets) - 1):
            lo, hi = vert_offsets[g], vert_offsets[g + 1]
            gf = faces[(faces >= lo).all(1) & (faces < hi).all(1)] - lo
            bv = body_verts[int(body_index[g])]
            nv = hi - lo
            all_faces = np.concatenate([gf, body_faces + nv]).astype(np.int32)
            rest = np.asfortranarray(np.concatenate([x[lo:hi].detach().cpu().numpy(), bv]))
            mesh = ipctk.CollisionMesh(rest, np.asfortranarray(ipctk.edges(all_faces)), np.asfortranarray(all_faces))
            if self_contact:
                mesh.can_collide = ipctk.make_static_obstacle_filter(nv)
            else:  # only garment–body pairs: one component for the garment, one for the body
                link_g = np.stack([np.zeros(nv - 1), np.arange(1, nv), np.arange(1, nv)], 1)
                link_b = np.stack([np.full(len(bv) - 1, nv), np.arange(nv + 1, nv + len(bv)),
                                   np.arange(nv + 1, nv + len(bv))], 1)
                comp = np.asfortranarray(np.concatenate([all_faces, link_g, link_b]).astype(np.int32))
                mesh.can_collide = ipctk.make_connected_components_filter(comp)
            self.meshes.append(mesh)
            self.body_pos.append(bv)
        self.potential = ipctk.BarrierPotential(dhat, stiffness)

    def _full(self, x_np: np.ndarray, g: int) -> np.ndarray:
        lo, hi = self.offsets[g], self.offsets[g + 1]
        return np.asfortranarray(np.concatenate([x_np[lo:hi], self.body_pos[g]]))

    def _collisions(self, full: np.ndarray, g: int):
        col = self.ipctk.NormalCollisions()
        col.build(self.meshes[g], full, self.dhat)
        return col

    def check_start(self, x_np: np.ndarray) -> None:
        for g, mesh in enumerate(self.meshes):
            if self.ipctk.has_intersections(mesh, self._full(x_np, g)):
                raise ValueError(f"garment {g} intersects its body (or itself) at the start state; IPC needs an "
                                 "intersection-free start: relax it with contact='penalty' first, or push it out "
                                 "with the collision handler")

    def energy(self, x_np: np.ndarray) -> np.ndarray:
        """Barrier energy per garment (G,) [J]."""
        out = np.zeros(len(self.meshes))
        for g, mesh in enumerate(self.meshes):
            full = self._full(x_np, g)
            out[g] = self.potential(self._collisions(full, g), mesh, full)
        return out

    def grad_hess(self, x_np: np.ndarray, *, project: bool = True) -> tuple[np.ndarray, sp.csc_matrix]:
        """Gradient (V, 3) and Hessian (3V × 3V) of the barrier; project=True: ipctk's per-collision
        PSD projection (eigenvalues clamped), else the exact Hessian."""
        num_verts = self.offsets[-1]
        grad = np.zeros((num_verts, 3))
        blocks = []
        method = self.ipctk.PSDProjectionMethod.CLAMP if project else self.ipctk.PSDProjectionMethod.NONE
        for g, mesh in enumerate(self.meshes):
            lo, hi = self.offsets[g], self.offsets[g + 1]
            full = self._full(x_np, g)
            col = self._collisions(full, g)
            gr = self.potential.gradient(col, mesh, full).reshape(-1, 3)
            grad[lo:hi] = gr[: hi - lo]
            hess = self.potential.hessian(col, mesh, full, method)
            n3 = 3 * (hi - lo)
            blocks.append(hess.tocsc()[:n3, :n3])
        return grad, sp.block_diag(blocks, format="csc")

    def max_step(self, x_np: np.ndarray, p_np: np.ndarray) -> np.ndarray:
        """Largest collision-free step length per garment along p (CCD), (G,)."""
        out = np.ones(len(self.meshes))
        for g, mesh in enumerate(self.meshes):
            out[g] = self.ipctk.compute_collision_free_stepsize(mesh, self._full(x_np, g),
                                                                self._full(x_np + p_np, g))
        return out

"""The force-driven GNN (paper Eqs. 7–9): encode-process-decode on the garment mesh graph."""

from __future__ import annotations

import torch
from torch import Tensor, nn


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
        sender, receiver = edge_index[0], edge_index[1]
        edges = edges + self.edge_mlp(torch.cat([edges, nodes[receiver], nodes[sender]], dim=-1))
        aggregated = torch.zeros_like(nodes).index_add_(0, receiver, edges)
        nodes = nodes + self.node_mlp(torch.cat([nodes, aggregated], dim=-1))
        return nodes, edges


class EncodeProcessDecode(nn.Module):
    """Encoders to a latent of width D, L processor blocks, a decoder without LayerNorm.

    Args:
        node_in, edge_in: raw (normalised) feature widths; out: decoder output width.
        latent: D; blocks: L; mlp_layers: Linear layers per MLP (the paper: 2).
        zero_init_output: start the decoder's last layer at zero (an untrained network outputs 0).
    Forward: nodes (N, node_in), edges (E, edge_in), edge_index (2, E) row 0 = sender → (N, out).
    """

    def __init__(self, node_in: int, edge_in: int, out: int, *, latent: int, blocks: int, mlp_layers: int = 2,
                 zero_init_output: bool = False) -> None:
        super().__init__()
        self.node_encoder = mlp(node_in, latent, latent, layers=mlp_layers)
        self.edge_encoder = mlp(edge_in, latent, latent, layers=mlp_layers)
        self.blocks = nn.ModuleList(ProcessorBlock(latent, mlp_layers=mlp_layers) for _ in range(blocks))
        self.decoder = mlp(latent, latent, out, layers=mlp_layers, layer_norm=False)
        if zero_init_output:  # the untrained network outputs 0: training starts from its input state
            nn.init.zeros_(self.decoder[-1].weight)
            nn.init.zeros_(self.decoder[-1].bias)

    def forward(self, nodes: Tensor, edges: Tensor, edge_index: Tensor) -> Tensor:
        h, e = self.node_encoder(nodes), self.edge_encoder(edges)
        for block in self.blocks:
            h, e = block(h, e, edge_index)
        return self.decoder(h)

"""Online feature normaliser (MeshGraphNets): running mean/std, frozen after a warm-up budget."""

from __future__ import annotations

import torch
from torch import Tensor, nn


class Normalizer(nn.Module):
    """Normalises features to zero mean, unit variance with statistics accumulated online.

    While `self.training` and fewer than `max_accumulations` batches have been seen, each call
    adds its batch to the statistics (a statistics-only warm-up is a few training-mode calls
    without optimiser steps). The statistics are buffers, so they are saved in checkpoints.

    Args:
        size: feature width C; inputs are (..., C).
        max_accumulations: batches after which the statistics freeze.
        std_epsilon: floor on the standard deviation (a constant feature stays finite).
    """

    def __init__(self, size: int, *, max_accumulations: int = 1000, std_epsilon: float = 1e-8) -> None:
        super().__init__()
        self.max_accumulations = max_accumulations
        self.std_epsilon = std_epsilon
        self.register_buffer("count", torch.zeros((), dtype=torch.float64))
        self.register_buffer("accumulations", torch.zeros((), dtype=torch.int64))
        self.register_buffer("sum", torch.zeros(size, dtype=torch.float64))
        self.register_buffer("sum_squares", torch.zeros(size, dtype=torch.float64))

    @torch.no_grad()
    def accumulate(self, features: Tensor) -> None:
        """Add a batch (..., C) to the statistics (distributed: the caller all-reduces buffers)."""
        flat = features.detach().reshape(-1, features.shape[-1]).to(torch.float64)
        self.count += flat.shape[0]
        self.sum += flat.sum(0)
        self.sum_squares += (flat * flat).sum(0)
        self.accumulations += 1

    def mean(self) -> Tensor:
        return self.sum / self.count.clamp_min(1.0)

    def std(self) -> Tensor:
        variance = self.sum_squares / self.count.clamp_min(1.0) - self.mean() ** 2
        return variance.clamp_min(0.0).sqrt().clamp_min(self.std_epsilon)

    def normalize_columns(self, features: Tensor, columns: slice) -> Tensor:
        """Features (..., C') normalised with the statistics of `columns` (C' of them), without
        adding to the statistics: quantities of the same kind as those columns found elsewhere."""
        mean, std = self.mean()[columns].to(features.dtype), self.std()[columns].to(features.dtype)
        return (features - mean) / std

    def forward(self, features: Tensor) -> Tensor:
        if self.training and int(self.accumulations) < self.max_accumulations:
            self.accumulate(features)
        return self.normalize_columns(features, slice(None))

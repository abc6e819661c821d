"""Values derived from a tensor, kept while that tensor lives unmodified: for what a solver derives
from the same cloth tensors dozens of times per drape (kernel-typed copies, split points)."""

from __future__ import annotations

import collections
import weakref
from collections.abc import Callable
from typing import TypeVar

from torch import Tensor

V = TypeVar("V")


class TensorMemo:
    """make(t) per tensor t, by the tensor's id, reused while t lives unmodified (its weak
    reference and version counter are checked, so a recycled id or an in-place change makes the
    value again); the `size` most recently used are kept."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._values: collections.OrderedDict[int, tuple[weakref.ref, int, object]] = collections.OrderedDict()

    def get(self, t: Tensor, make: Callable[[Tensor], V]) -> V:
        hit = self._values.get(id(t))
        if hit is not None and hit[0]() is t and hit[1] == t._version:
            self._values.move_to_end(id(t))
            return hit[2]
        value = make(t)
        self._values[id(t)] = (weakref.ref(t), t._version, value)
        self._values.move_to_end(id(t))
        while len(self._values) > self.size:
            self._values.popitem(last=False)
        return value

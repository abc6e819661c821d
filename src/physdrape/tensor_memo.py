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
    value again); the `size` most recently used are kept, and a value is let go when its tensor
    dies (a batch's derived copies do not outlive the batch)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._values: collections.OrderedDict[int, tuple[weakref.ref, int, object]] = collections.OrderedDict()

    def get(self, t: Tensor, make: Callable[[Tensor], V]) -> V:
        hit = self._values.get(id(t))
        if hit is not None and hit[0]() is t and hit[1] == t._version:
            self._values.move_to_end(id(t))
            return hit[2]
        value = make(t)
        key = id(t)
        self._values[key] = (weakref.ref(t, lambda ref: self._forget(key, ref)), t._version, value)
        self._values.move_to_end(id(t))
        while len(self._values) > self.size:
            self._values.popitem(last=False)
        return value

    def _forget(self, key: int, ref: weakref.ref) -> None:
        """The tensor of `ref` died: drop its value (unless the id already holds a newer one)."""
        hit = self._values.get(key)
        if hit is not None and hit[0] is ref:
            del self._values[key]

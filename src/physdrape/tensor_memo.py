"""Values derived from a tensor, kept while that tensor lives unmodified: for what a solver derives
from the same cloth tensors dozens of times per drape (kernel-typed copies, split points)."""

from __future__ import annotations

import collections
import threading
import weakref
from collections.abc import Callable
from typing import TypeVar

from torch import Tensor

V = TypeVar("V")


class TensorMemo:
    """make(t) per tensor t, by the tensor's id, reused while t lives unmodified (its weak
    reference and version counter are checked, so a recycled id or an in-place change makes the
    value again); the `size` most recently used are kept, and a value is let go when its tensor
    dies (a batch's derived copies do not outlive the batch). Safe to share between threads (a
    value may then be made twice, once per thread, and either kept)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._values: collections.OrderedDict[int, tuple[weakref.ref, int, object]] = collections.OrderedDict()
        # reentrant: a weak reference's callback (`_forget`) can run inside a locked section, when
        # that section's allocation triggers the garbage collector
        self._lock = threading.RLock()

    def get(self, t: Tensor, make: Callable[[Tensor], V]) -> V:
        key = id(t)
        with self._lock:
            hit = self._values.get(key)
            if hit is not None and hit[0]() is t and hit[1] == t._version:
                self._values.move_to_end(key)
                return hit[2]
        value = make(t)
        with self._lock:
            self._values[key] = (weakref.ref(t, lambda ref: self._forget(key, ref)), t._version, value)
            self._values.move_to_end(key)
            while len(self._values) > self.size:
                self._values.popitem(last=False)
        return value

    def _forget(self, key: int, ref: weakref.ref) -> None:
        """The tensor of `ref` died: drop its value (unless the id already holds a newer one)."""
        with self._lock:
            hit = self._values.get(key)
            if hit is not None and hit[0] is ref:
                del self._values[key]

"""Values derived from a tensor, kept while that tensor lives unmodified: for what a solver derives
from the same cloth tensors dozens of times per drape (kernel-typed copies, split points);
values derived from a few objects, kept while those objects live (`IdentityMemo`: a batch packed
from the same garments, its cloth in the same materials); and values made per key, the most
recently used kept (`KeyedMemo`: what a pipeline derives from each garment template, bounded so
that draping thousands of garments in one process does not hold every garment's)."""

from __future__ import annotations

import collections
import threading
import weakref
from collections.abc import Callable, Hashable
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


class IdentityMemo:
    """make() per tuple of objects (by identity) and a hashable key, reused while those objects
    live (weak references are checked, so a recycled id makes the value again); the `size` most
    recently used are kept. The objects must be immutable in what make() reads. Safe to share
    between threads (a value may then be made twice, once per thread, and either kept)."""

    def __init__(self, size: int) -> None:
        self.size = size
        self._values: collections.OrderedDict[tuple, tuple[tuple[weakref.ref, ...], object]] = collections.OrderedDict()
        self._lock = threading.Lock()

    def get(self, objects: tuple, key: Hashable, make: Callable[[], V]) -> V:
        full = (tuple(id(o) for o in objects), key)
        with self._lock:
            hit = self._values.get(full)
            if hit is not None and all(ref() is o for ref, o in zip(hit[0], objects)):
                self._values.move_to_end(full)
                return hit[1]
        value = make()
        with self._lock:
            self._values[full] = (tuple(weakref.ref(o) for o in objects), value)
            self._values.move_to_end(full)
            while len(self._values) > self.size:
                self._values.popitem(last=False)
        return value

    def clear(self) -> None:
        """Forget every value."""
        with self._lock:
            self._values.clear()


class KeyedMemo:
    """make() per hashable key, the `size` most recently used kept (the least recently used is
    let go when a new key would make more). Safe to share between threads (a value may then be
    made twice, once per thread, and either kept)."""

    def __init__(self, size: int) -> None:
        if size < 1:
            raise ValueError(f"a KeyedMemo keeps at least one value, got size {size}")
        self.size = size
        self._values: collections.OrderedDict[Hashable, object] = collections.OrderedDict()
        self._lock = threading.Lock()

    def get(self, key: Hashable, make: Callable[[], V]) -> V:
        with self._lock:
            if key in self._values:
                self._values.move_to_end(key)
                return self._values[key]
        value = make()
        with self._lock:
            self._values[key] = value
            self._values.move_to_end(key)
            while len(self._values) > self.size:
                self._values.popitem(last=False)
        return value

    def __contains__(self, key: Hashable) -> bool:
        with self._lock:
            return key in self._values

    def __len__(self) -> int:
        with self._lock:
            return len(self._values)

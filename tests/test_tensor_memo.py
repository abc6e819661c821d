"""`TensorMemo`: values derived from a tensor, by identity, remade after an in-place change, let go
when the tensor dies, the most recently used kept; `IdentityMemo`: values derived from a few
objects, by identity and a key, and what uses it (a batch packed again, its cloth built again);
`KeyedMemo`: values made per key, the most recently used kept."""

import gc

import torch

import pytest

from physdrape.tensor_memo import IdentityMemo, KeyedMemo, TensorMemo


def test_a_value_is_made_once_per_tensor_and_again_after_an_in_place_change():
    memo, made = TensorMemo(4), []

    def make(t):
        made.append(1)
        return t * 2

    t = torch.arange(3.0)
    first = memo.get(t, make)
    assert memo.get(t, make) is first and len(made) == 1
    t.add_(1.0)  # the version counter moves: the value is made again
    assert torch.equal(memo.get(t, make), torch.tensor([2.0, 4.0, 6.0])) and len(made) == 2


def test_a_value_is_let_go_when_its_tensor_dies():
    memo = TensorMemo(4)
    t = torch.zeros(1000)
    memo.get(t, lambda u: torch.ones(1000))
    assert len(memo._values) == 1
    del t
    gc.collect()
    assert len(memo._values) == 0


def test_the_most_recently_used_are_kept():
    memo = TensorMemo(2)
    tensors = [torch.zeros(1) for _ in range(3)]
    for t in tensors:
        memo.get(t, lambda u: u + 1)
    assert set(memo._values) == {id(tensors[1]), id(tensors[2])}


def test_a_recycled_id_does_not_return_another_tensors_value():
    memo = TensorMemo(8)
    for k in range(50):  # freed tensors' ids come back: each must get its own value
        t = torch.full((2,), float(k))
        assert float(memo.get(t, lambda u: u.clone())[0]) == k
        del t


def test_identity_memo_reuses_a_value_for_the_same_objects_and_key_only():
    class Thing:
        pass

    memo, a, b = IdentityMemo(2), Thing(), Thing()
    first = memo.get((a, b), "k", lambda: object())
    assert memo.get((a, b), "k", lambda: object()) is first
    assert memo.get((b, a), "k", lambda: object()) is not first  # the order counts
    assert memo.get((a, b), "other", lambda: object()) is not first  # so does the key
    assert memo.get((a, b), "k", lambda: object()) is not first  # the oldest let go (size 2)
    memo.clear()
    assert not memo._values


def test_the_same_garments_pack_into_the_same_batch_and_cloth():
    from physdrape.geometry.garment import Garment, GarmentBatch
    from physdrape.geometry.primitives import grid_sheet
    from physdrape.physics import Cloth, Material

    sheet = Garment.from_mesh(*grid_sheet(4, 3, width=0.4, height=0.3), name="sheet")
    other = Garment.from_mesh(*grid_sheet(4, 3, width=0.4, height=0.3), name="sheet")  # equal, not the same
    batch = GarmentBatch.pack([sheet, other])
    assert GarmentBatch.pack([sheet, other]) is batch and GarmentBatch.pack([other, sheet]) is not batch
    assert GarmentBatch.pack([sheet, sheet]) is not batch and batch.to(batch.dtype) is batch
    assert batch.to(torch.float32).dtype == torch.float32
    cloth = Cloth.build(batch)
    assert Cloth.build(batch) is cloth and Cloth.build(batch, Material(density=0.3)) is not cloth
    assert Cloth.build(batch, [Material(), Material()]) is cloth  # the default material for each


def test_a_keyed_value_is_made_once_and_the_most_recently_used_are_kept():
    memo, made = KeyedMemo(2), []

    def make(key):
        def value():
            made.append(key)
            return [key]
        return value

    first = memo.get("a", make("a"))
    assert memo.get("a", make("a")) is first and made == ["a"]
    memo.get("b", make("b"))
    memo.get("a", make("a"))  # "a" used last: "b" is the least recently used
    memo.get("c", make("c"))
    assert len(memo) == 2 and "a" in memo and "c" in memo and "b" not in memo
    assert memo.get("b", make("b")) == ["b"] and made == ["a", "b", "c", "b"]  # made again once let go
    with pytest.raises(ValueError, match="at least one"):
        KeyedMemo(0)

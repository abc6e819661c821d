"""The CATEGORY:SEED garments kept on disk: made once, read back the same bit for bit, never read
back for other code, and a cache that cannot be written only costs generating again."""

from __future__ import annotations

import numpy as np
import pytest

from physdrape.garments import generated_cache
from physdrape.garments.catalogue import generate_valid
from physdrape.garments.generated_cache import CACHE_FOLDER, generated_garment


@pytest.fixture
def counted(monkeypatch):
    """generate_valid as the cache calls it, counting its calls."""
    calls = []

    def generate(category, seed, **kwargs):
        calls.append((category, seed))
        return generate_valid(category, seed, **kwargs)

    monkeypatch.setattr(generated_cache, "generate_valid", generate)
    return calls


def test_made_once_then_read_back_bit_for_bit(tmp_path, counted):
    name, verts, faces = generated_garment("shorts", 1, root=tmp_path)
    again = generated_garment("shorts", 1, root=tmp_path)
    fresh, _ = generate_valid("shorts", 1)
    assert counted == [("shorts", 1)]
    assert name == again[0] == fresh.name == "shorts_1"
    assert np.array_equal(again[1], fresh.verts) and again[1].dtype == np.float64
    assert np.array_equal(again[2], fresh.faces) and np.array_equal(faces, fresh.faces)
    files = list((tmp_path / CACHE_FOLDER).rglob("*.ply"))
    assert [f.name for f in files] == ["shorts_1.ply"] and files[0].parent.name == generated_cache.code_key()


def test_other_code_is_never_read_back_and_its_folder_goes(tmp_path, counted, monkeypatch):
    generated_garment("shorts", 1, root=tmp_path)
    old = tmp_path / CACHE_FOLDER / generated_cache.code_key()
    monkeypatch.setattr(generated_cache, "code_key", lambda: "0" * 16)
    generated_garment("shorts", 1, root=tmp_path)
    assert len(counted) == 2
    assert not old.exists() and (tmp_path / CACHE_FOLDER / ("0" * 16) / "shorts_1.ply").is_file()


def test_an_unreadable_file_is_made_again(tmp_path, counted):
    _, verts, _ = generated_garment("shorts", 1, root=tmp_path)
    path = next((tmp_path / CACHE_FOLDER).rglob("shorts_1.ply"))
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\n")
    _, again, _ = generated_garment("shorts", 1, root=tmp_path)
    assert len(counted) == 2 and np.array_equal(again, verts)
    assert np.array_equal(generated_garment("shorts", 1, root=tmp_path)[1], verts) and len(counted) == 2


def test_an_unwritable_cache_only_costs_generating(tmp_path, counted):
    blocked = tmp_path / "not_a_folder"
    blocked.write_text("a file where the cache's folder would be")
    for _ in range(2):
        name, verts, _ = generated_garment("shorts", 1, root=blocked)
        assert name == "shorts_1" and len(verts) > 100
    assert len(counted) == 2


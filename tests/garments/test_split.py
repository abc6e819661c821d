import json
from pathlib import Path

import pytest

from physdrape.garments import GarmentCategory, GarmentTemplate, load_split, make_split
from physdrape.garments.split import main, split_entries

pytestmark = pytest.mark.anny


def _tree(d: Path) -> dict:
    return {str(p.relative_to(d)): p.read_bytes() for p in sorted(d.rglob("*")) if p.is_file()}


def test_split_is_reproducible_from_its_seed(tmp_path, body):
    a, b = tmp_path / "a", tmp_path / "b"
    make_split(a, seed=3, num_train=1, num_test=4)
    main(["--out", str(b), "--seed", "3", "--num-train", "1", "--num-test", "4"])  # the CLI path
    ta, tb = _tree(a), _tree(b)
    assert ta.keys() == tb.keys() and len(ta) == 6  # manifest + 5 garments
    assert ta == tb  # byte for byte
    manifest = json.loads((a / "manifest.json").read_text())
    test = [g for g in manifest["garments"] if g["subset"] == "test"]
    assert {g["category"] for g in test} == {c.value for c in GarmentCategory}
    for g in manifest["garments"]:
        assert set(g) >= {"params", "num_verts", "num_faces", "sha256", "file", "seed", "attempt"}
    loaded = load_split(a, "test")
    assert [g.num_verts for g in loaded] == [g["num_verts"] for g in test]
    assert all(isinstance(g, GarmentTemplate) for g in loaded)


def test_train_and_test_draws_are_disjoint():
    entries = split_entries(0, 600, 30)
    train = {e["seed"] for e in entries if e["subset"] == "train"}
    test = {e["seed"] for e in entries if e["subset"] == "test"}
    assert len(train) == 600 and len(test) == 30 and not train & test
    assert split_entries(0, 600, 30) == entries
    assert split_entries(1, 600, 30) != entries


def test_load_split_detects_changes(tmp_path, body):
    make_split(tmp_path, seed=5, num_train=0, num_test=1)
    ply = next((tmp_path / "test").glob("*.ply"))
    ply.write_bytes(ply.read_bytes()[:-4] + b"\0\0\0\0")
    with pytest.raises(ValueError, match="sha256"):
        load_split(tmp_path, "test")
    with pytest.raises(FileNotFoundError, match="generate the split"):
        load_split(tmp_path / "nowhere", "test")

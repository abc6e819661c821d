import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from physdrape.garments import GarmentCategory, GarmentTemplate, load_split, make_split
from physdrape.garments import split as split_module
from physdrape.garments.catalogue import generate_valid
from physdrape.garments.io import sha256_file
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


def test_lazy_generation_makes_only_the_garments_asked_for_and_equals_the_full_split(tmp_path, tiny_split):
    # The first 2 training garments of the protocol's 600/30 split, in 2 processes (the CLI path):
    # exactly those files are made, byte for byte those of the tiny 2 + 2 split of the same seed.
    lazy, full = tmp_path / "lazy", Path(tiny_split)
    main(["--out", str(lazy), "--subset", "train", "--count", "2", "--workers", "2"])
    assert sorted(_tree(lazy)) == ["manifest.json", "train/0000_tshirt.ply", "train/0001_longsleeve.ply"]
    for name in ("train/0000_tshirt.ply", "train/0001_longsleeve.ply"):
        assert sha256_file(lazy / name) == sha256_file(full / name), name
    manifest, reference = (json.loads((d / "manifest.json").read_text()) for d in (lazy, full))
    assert (manifest["num_train"], manifest["num_test"]) == (600, 30)
    assert manifest["garments"] == [g for g in reference["garments"] if g["subset"] == "train"]
    assert [g.name for g in load_split(lazy, "train", count=2)] == ["0000_tshirt", "0001_longsleeve"]
    with pytest.raises(ValueError, match="holds 2 of the 600 train garments asked for"):
        load_split(lazy, "train")  # the whole subset was not generated: the error says so
    with pytest.raises(ValueError, match="holds 0 of the 1 test garments asked for .the split has 30"):
        load_split(lazy, "test", count=1)


def test_an_interrupted_generation_resumes_with_only_the_missing_garments(tmp_path, tiny_split, monkeypatch):
    split = tmp_path / "split"
    shutil.copytree(tiny_split, split)
    reference = _tree(split)
    manifest = json.loads((split / "manifest.json").read_text())
    manifest["garments"] = [g for g in manifest["garments"] if g["subset"] == "train"]  # no test garments yet
    (split / "manifest.json").write_text(json.dumps(manifest))
    for ply in (split / "test").glob("*.ply"):
        ply.unlink()
    (split / "train" / "0001_longsleeve.ply").unlink()  # a file lost since
    made = []

    def counted(category, seed, **kwargs):
        if len(made) == 2 and interrupt:
            raise KeyboardInterrupt  # Ctrl-C while the third garment is being made
        made.append(category)
        return generate_valid(category, seed, **kwargs)

    monkeypatch.setattr(split_module, "generate_valid", counted)
    interrupt = True
    with pytest.raises(KeyboardInterrupt):
        make_split(split, seed=0, num_train=2, num_test=2, workers=1)
    kept = json.loads((split / "manifest.json").read_text())["garments"]
    assert made == ["longsleeve", "tshirt"]  # train 1, then test 0
    assert [g["file"] for g in kept][-1] == "test/0000_tshirt.ply"  # recorded before Ctrl-C stopped it

    interrupt = False
    make_split(split, seed=0, num_train=2, num_test=2, workers=1)
    assert made == ["longsleeve", "tshirt", "longsleeve"]  # only test 1 was left
    assert _tree(split) == reference  # garments and manifest byte for byte
    make_split(split, seed=0, num_train=2, num_test=2, workers=1)
    assert len(made) == 3  # nothing left to make


def test_a_split_directory_refuses_garments_of_another_split(tmp_path, tiny_split):
    split = tmp_path / "split"
    shutil.copytree(tiny_split, split)
    with pytest.raises(ValueError, match="generate into another directory"):
        make_split(split, seed=1, num_train=2, num_test=2)
    with pytest.raises(ValueError, match="'num_train': 2"):
        make_split(split, seed=0)  # the protocol's 600 / 30, but this directory is a 2 / 2 split
    (split / "manifest.json").write_text('{"format": "physdrape-garment-split/1"}')
    with pytest.raises(ValueError, match="format"):
        load_split(split, "train")


def test_garments_do_not_depend_on_the_callers_torch_threads(tmp_path):
    # Two fresh processes, one and two torch threads, generate the same entry in one and two
    # worker processes: the same bytes (the canonical body is built with one thread either way).
    code = ("import sys, torch; torch.set_num_threads(int(sys.argv[1])); from physdrape.garments.split import "
            "make_split; m = make_split(sys.argv[2], subset='test', count=1, workers=int(sys.argv[1])); "
            "print(m['garments'][0]['sha256'])")
    runs = [subprocess.Popen([sys.executable, "-c", code, str(n), str(tmp_path / str(n))], stdout=subprocess.PIPE,
                             stderr=subprocess.DEVNULL, text=True) for n in (1, 2)]
    digests = [run.communicate(timeout=120)[0].strip() for run in runs]
    assert all(run.returncode == 0 for run in runs) and len(digests[0]) == 64
    assert digests[0] == digests[1]
    assert sha256_file(tmp_path / "2" / "test" / "0000_tshirt.ply") == digests[0]

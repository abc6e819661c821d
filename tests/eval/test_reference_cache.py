"""The reference cache: a hit gives the numbers of the run it stored, anything the oracle depends
on changes the key, and a damaged entry is recomputed with a warning."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest
import torch
import trimesh

from physdrape.eval.config import EvalConfig
from physdrape.eval.evaluate import Contact, oracle_settings, skinned_oracle
from physdrape.eval.reference_cache import ReferenceCache, reference_key
from physdrape.geometry.garment import Garment, GarmentBatch
from physdrape.geometry.primitives import grid_sheet
from physdrape.geometry.proximity import BodySurface
from physdrape.model import DrapeInput
from physdrape.physics import Cloth, Material
from physdrape.physics.contact import DEFAULT_MARGIN, DEFAULT_STIFFNESS
from physdrape.physics.layers import LayerOrder
from physdrape.physics.stitches import Stitches

CONTACT = Contact(DEFAULT_STIFFNESS, DEFAULT_MARGIN)
CONFIG = EvalConfig(oracle_max_iters=3, oracle_budget_s=60.0)  # max_iters stops it: deterministic


def sheet_on_box(material: Material = Material(), lift: float = 0.503) -> DrapeInput:
    """A 20 cm, 25-vertex sheet over the edge of a 1 m box."""
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    bodies = BodySurface(torch.tensor(np.asarray(box.vertices)), torch.tensor(np.asarray(box.faces)))
    verts, faces = grid_sheet(5, 5, width=0.2, height=0.2)
    batch = GarmentBatch.pack([Garment.from_mesh(verts + np.array([0.4, lift, -0.1]), faces, name="sheet")])
    return DrapeInput(batch, Cloth.build(batch, material), batch.rest.clone(), bodies,
                      torch.zeros_like(batch.vert_garment))


def without(record: dict, *keys: str) -> dict:
    return {k: v for k, v in record.items() if k not in keys}


def test_a_hit_gives_the_stored_run_and_its_numbers(tmp_path):
    batch, cache = sheet_on_box(), ReferenceCache(tmp_path)
    first = skinned_oracle(batch, None, CONFIG, CONTACT, cache)
    second = skinned_oracle(batch, None, CONFIG, CONTACT, cache)
    assert (first["cached"], second["cached"]) == (False, True) and (cache.hits, cache.misses) == (1, 1)
    assert without(first, "cached") == without(second, "cached")
    assert first["iterations"] == 3 and first["energy_total"] < first["history"][0]["energy"]  # it did relax
    (x_file,) = tmp_path.glob("*.safetensors")
    entry = json.loads(x_file.with_suffix(".json").read_text())
    assert entry["record"]["oracle_energy_terms"]["total"] == first["oracle_energy_total"]


def test_a_changed_setting_material_body_or_start_misses():
    batch = sheet_on_box()
    settings = oracle_settings(CONFIG, CONTACT)
    key = reference_key(batch, batch.x_init, settings)
    assert key == reference_key(sheet_on_box(), batch.x_init.clone(), dict(settings))
    others = [
        reference_key(batch, batch.x_init, oracle_settings(replace(CONFIG, oracle_tol=2e-2), CONTACT)),
        reference_key(batch, batch.x_init, oracle_settings(replace(CONFIG, oracle_max_iters=4), CONTACT)),
        reference_key(batch, batch.x_init, oracle_settings(replace(CONFIG, oracle_budget_s=30.0), CONTACT)),
        reference_key(batch, batch.x_init, oracle_settings(replace(CONFIG, dtype="float64"), CONTACT)),
        reference_key(batch, batch.x_init, oracle_settings(CONFIG, Contact(2 * DEFAULT_STIFFNESS, DEFAULT_MARGIN))),
        reference_key(batch, batch.x_init, oracle_settings(CONFIG, Contact(DEFAULT_STIFFNESS, 2 * DEFAULT_MARGIN))),
        reference_key(sheet_on_box(Material(density=0.2)), batch.x_init, settings),
        reference_key(replace(batch, bodies=BodySurface(batch.bodies.verts + 1e-6, batch.bodies.faces)),
                      batch.x_init, settings),
        reference_key(batch, batch.x_init + 1e-6, settings),
        reference_key(sheet_on_box(lift=0.51), batch.x_init, settings),  # the garment's rest positions
    ]
    # the grip's, the stitches' and the layer order's terms: the anchors, stiffnesses, normals
    layered = replace(batch, cloth=replace(batch.cloth, layers=LayerOrder.build(
        torch.tensor([[0, 1]]), torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64))))
    moved = replace(layered, cloth=replace(layered.cloth, layers=LayerOrder.build(
        torch.tensor([[0, 1]]), torch.tensor([[0.0, 0.0, 1.0]], dtype=torch.float64))))
    stitched = replace(batch, cloth=replace(batch.cloth, stitches=Stitches(
        torch.tensor([[0, 2]]), torch.zeros(1, dtype=torch.float64), torch.ones(1, dtype=torch.float64))))
    others += [reference_key(b, batch.x_init, settings) for b in (layered, moved, stitched)]
    assert len({key, *others}) == len(others) + 1


def test_the_key_of_a_following_layer_order_names_how_often_the_oracle_searches_it(monkeypatch):
    """A layer order that the oracle completes as it goes (`LayerOrder.follows`) keys its entry by
    how far a vertex moves before the oracle searches the pairs again; a fixed one does not."""
    import physdrape.eval.reference_cache as reference_cache

    batch = sheet_on_box()
    settings = oracle_settings(CONFIG, CONTACT)
    fixed = LayerOrder.build(torch.tensor([[0, 1]]), torch.tensor([[0.0, 1.0, 0.0]], dtype=torch.float64))
    follows = replace(fixed, piece=torch.zeros(batch.cloth.num_verts, dtype=torch.int64),
                      together=torch.ones(1, 1, dtype=torch.bool), depth=torch.zeros(batch.cloth.num_verts,
                                                                                      dtype=torch.float64),
                      faces=batch.garments.faces)
    keys = {}
    for name, layers in (("fixed", fixed), ("follows", follows)):
        layered = replace(batch, cloth=replace(batch.cloth, layers=layers))
        before = reference_key(layered, batch.x_init, settings)
        monkeypatch.setattr(reference_cache, "FOLLOW_MOVE", 2 * reference_cache.FOLLOW_MOVE)
        keys[name] = (before, reference_key(layered, batch.x_init, settings))
        monkeypatch.undo()
    assert keys["fixed"][0] == keys["fixed"][1] and keys["follows"][0] != keys["follows"][1]


def test_the_key_of_a_garment_of_several_pieces_names_how_the_oracle_keeps_them_apart(monkeypatch):
    """A garment of two pieces keys its entry by the oracle's guard against crossed pieces (its
    hold rounds); a garment of one piece, which the guard never touches, does not."""
    import physdrape.eval.reference_cache as reference_cache

    settings = oracle_settings(CONFIG, CONTACT)
    one = sheet_on_box()
    verts, faces = grid_sheet(5, 5, width=0.2, height=0.2)
    two_pieces = np.concatenate([verts, verts + np.array([0.0, 0.01, 0.0])]) + np.array([0.4, 0.503, -0.1])
    batch = GarmentBatch.pack([Garment.from_mesh(two_pieces, np.concatenate([faces, faces + len(verts)]))])
    two = DrapeInput(batch, Cloth.build(batch), batch.rest.clone(), one.bodies, torch.zeros_like(batch.vert_garment))
    keys = {}
    for name, inst in (("one", one), ("two", two)):
        before = reference_key(inst, inst.x_init, settings)
        monkeypatch.setattr(reference_cache, "HOLD_ROUNDS", reference_cache.HOLD_ROUNDS + 1)
        keys[name] = (before, reference_key(inst, inst.x_init, settings))
        monkeypatch.undo()
    assert keys["one"][0] == keys["one"][1] and keys["two"][0] != keys["two"][1]


def test_a_changed_setting_runs_the_oracle_again(tmp_path):
    batch, cache = sheet_on_box(), ReferenceCache(tmp_path)
    skinned_oracle(batch, None, CONFIG, CONTACT, cache)
    other = skinned_oracle(batch, None, replace(CONFIG, oracle_max_iters=1), CONTACT, cache)
    assert not other["cached"] and other["iterations"] == 1 and len(list(tmp_path.glob("*.json"))) == 2


@pytest.mark.parametrize("damage", ["truncated positions", "flipped byte", "bad json", "other key", "no positions"])
def test_a_damaged_entry_is_recomputed_with_a_warning(tmp_path, damage):
    batch, cache = sheet_on_box(), ReferenceCache(tmp_path)
    first = skinned_oracle(batch, None, CONFIG, CONTACT, cache)
    (x_file,) = tmp_path.glob("*.safetensors")
    record_file = x_file.with_suffix(".json")
    data = x_file.read_bytes()
    if damage == "truncated positions":
        x_file.write_bytes(data[: len(data) // 2])
    elif damage == "flipped byte":
        x_file.write_bytes(data[:-1] + bytes([data[-1] ^ 1]))
    elif damage == "bad json":
        record_file.write_text(record_file.read_text()[:40])
    elif damage == "other key":
        record_file.write_text(record_file.read_text().replace(x_file.stem, "0" * 32))
    else:
        x_file.unlink()
    with pytest.warns(RuntimeWarning, match="is damaged"):
        again = skinned_oracle(batch, None, CONFIG, CONTACT, cache)
    assert not again["cached"]
    assert without(again, "cached", "wall_s", "history") == without(first, "cached", "wall_s", "history")
    assert skinned_oracle(batch, None, CONFIG, CONTACT, cache)["cached"]  # rewritten whole


def test_positions_without_their_record_are_a_quiet_miss(tmp_path, recwarn):
    batch, cache = sheet_on_box(), ReferenceCache(tmp_path)
    skinned_oracle(batch, None, CONFIG, CONTACT, cache)
    (record_file,) = tmp_path.glob("*.json")
    record_file.unlink()  # as when the run stopped between writing the two files
    assert not skinned_oracle(batch, None, CONFIG, CONTACT, cache)["cached"]
    assert not [w for w in recwarn if issubclass(w.category, RuntimeWarning)]


def test_an_unwritable_cache_is_a_warning_not_a_failure(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    with pytest.warns(RuntimeWarning, match="could not write"):
        record = skinned_oracle(sheet_on_box(), None, CONFIG, CONTACT, ReferenceCache(blocker / "cache"))
    assert not record["cached"] and record["iterations"] == 3

"""The evaluation's instance layout: an instance (its garment and its body) does not depend on how
many instances are drawn, nor on the poses per garment."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
import torch

from physdrape.body.pool import BodyPool
from physdrape.eval.config import EvalConfig
from physdrape.eval.instances import body_seed, garment_category, layout, makehuman_instances, split_instances
from physdrape.pipeline import POSE_DTYPE

SUIT_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0" / "female_casualsuit01"


@pytest.fixture(scope="module")
def config(tiny_split) -> EvalConfig:
    return EvalConfig(split_dir=tiny_split, oracle=False)


def test_layout_takes_every_garment_once_before_any_twice():
    assert layout(3, 7) == [(0, 0), (1, 0), (2, 0), (0, 1), (1, 1), (2, 1), (0, 2)]
    assert layout(3, 2) == layout(3, 7)[:2]


def test_body_seeds_depend_on_seed_set_garment_and_pose_alone():
    seeds = {body_seed(s, name, g, k) for s in (0, 1) for name in ("test", "makehuman") for g in (0, 1) for k in (0, 1)}
    assert len(seeds) == 16
    assert body_seed(0, "test", 3, 1) == body_seed(0, "test", 3, 1)


def test_category_is_read_from_split_names_only():
    assert [garment_category(n) for n in ("0000_tshirt", "0013_longsleeve", "0002_tanktop", "0027_croptop")] == [
        "tshirt", "longsleeve", "tanktop", "croptop"]
    assert garment_category("female_casualsuit01") is None and garment_category("0001_skirt") is None


def test_pool_from_seeds_is_the_same_body_in_any_pool(anny_body):
    alone = BodyPool.from_seeds(anny_body, [7], dtype=POSE_DTYPE)
    among = BodyPool.from_seeds(anny_body, [5, 6, 7], dtype=POSE_DTYPE)
    assert torch.equal(alone.verts[0], among.verts[2])
    assert torch.equal(alone.vertex_transforms[0], among.vertex_transforms[2])
    assert torch.equal(BodyPool(anny_body, 1, seed=7, dtype=POSE_DTYPE).verts[0], alone.verts[0])
    assert not torch.equal(among.verts[0], among.verts[1])


def test_default_is_the_whole_test_split_and_instances_takes_its_first_n(config, anny_body):
    whole = split_instances(config, anny_body)
    assert [(i.garment, i.pose_index) for i in whole] == [("0000_tshirt", 0), ("0001_longsleeve", 0)]
    two_poses = split_instances(replace(config, poses_per_garment=2), anny_body)
    assert [(i.garment_index, i.pose_index) for i in two_poses] == [(0, 0), (1, 0), (0, 1), (1, 1)]
    assert [i.body_seed for i in two_poses[:2]] == [i.body_seed for i in whole]
    assert len({i.body_seed for i in two_poses}) == 4
    first = split_instances(replace(config, instances=1), anny_body)
    assert [(i.garment, i.body_seed) for i in first] == [(whole[0].garment, whole[0].body_seed)]
    three = split_instances(replace(config, instances=3), anny_body)  # the 3rd: garment 0 in its second pose
    assert [(i.garment_index, i.pose_index, i.body_seed) for i in three] == [
        (i.garment_index, i.pose_index, i.body_seed) for i in two_poses[:3]]


def test_an_instance_is_the_same_garment_and_body_whatever_the_count(config, anny_body):
    one = split_instances(replace(config, instances=1), anny_body)[0].batch()
    three = split_instances(replace(config, instances=3), anny_body)[0].batch()
    torch.testing.assert_close(one.drape.garments.rest, three.drape.garments.rest, rtol=0, atol=0)
    torch.testing.assert_close(one.drape.bodies.verts, three.drape.bodies.verts, rtol=0, atol=0)
    torch.testing.assert_close(one.drape.x_init, three.drape.x_init, rtol=0, atol=0)
    torch.testing.assert_close(one.skinned, three.skinned, rtol=0, atol=0)


def test_bad_layout_settings_are_refused():
    with pytest.raises(ValueError, match="instances must be ≥ 1"):
        EvalConfig(instances=0)
    with pytest.raises(ValueError, match="poses_per_garment must be ≥ 1"):
        EvalConfig(poses_per_garment=0)
    with pytest.raises(ValueError, match="seed must be ≥ 0"):
        EvalConfig(seed=-1)


@pytest.mark.skipif(not (SUIT_DIR / "female_casualsuit01.mhclo").is_file(), reason=f"MakeHuman CC0 suit not found at {SUIT_DIR}")
def test_a_makehuman_instance_is_worn_as_the_draper_wears_the_suit(tmp_path, anny_body):
    from physdrape.api import Draper

    (tmp_path / SUIT_DIR.name).symlink_to(SUIT_DIR)
    [instance], notes = makehuman_instances(EvalConfig(makehuman_dir=str(tmp_path), oracle=False), anny_body)
    assert notes == []
    batch = instance.batch()
    cloth = batch.drape.cloth
    assert cloth.grip is not None and cloth.layers is not None  # the energy the oracle minimises has them
    pool = BodyPool.from_seeds(anny_body, [instance.body_seed], dtype=POSE_DTYPE)
    [res] = Draper().drape(str(SUIT_DIR / "female_casualsuit01.mhclo"), shape=pool.shapes[0].tolist(),
                           pose=pool.poses[0])
    x_init = torch.as_tensor(res.x_init, dtype=batch.drape.x_init.dtype)
    torch.testing.assert_close(batch.drape.x_init, x_init, rtol=0, atol=1e-6)  # sized to fit, as Draper does
    assert not torch.equal(batch.skinned, batch.drape.x_init)  # the oracle's start: skinned from the same rest

"""Training on procedural outfits beside the tops: the split's outfits subset, the templates'
order (the held-out tops stay last) and the outfits worn with the waistband gripped and the
pieces in layer order, in the samples and the cached teacher drapes."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from physdrape.garments.outfits import OutfitParams
from physdrape.garments.split import load_or_generate, load_split, make_split
from physdrape.model import ModelConfig
from physdrape.physics.energy import drape_energies, total_energy
from physdrape.physics.material import Material
from physdrape.pipeline import DrapePipeline
from physdrape.train.data import DataConfig, DrapeSource, load_templates

pytestmark = pytest.mark.anny

SMALL = ModelConfig(latent=8, blocks=3, levels=1, zero_init_output=True)


@pytest.fixture(scope="module")
def split_with_outfit(tmp_path_factory) -> str:
    out = tmp_path_factory.mktemp("split_with_outfit")
    make_split(out, seed=0, num_train=2, num_test=0, num_outfits=1)
    return str(out)


def test_split_holds_outfits_as_asked(split_with_outfit):
    manifest = json.loads((Path(split_with_outfit) / "manifest.json").read_text())
    assert manifest["num_outfits"] == 1 and manifest["num_train"] == 2
    (outfit,) = load_split(split_with_outfit, "outfits")
    assert isinstance(outfit.params, OutfitParams) and outfit.name == "0000_outfit"
    with pytest.raises(ValueError, match="say how many outfits"):
        load_or_generate(split_with_outfit, "outfits")


def test_outfits_train_beside_the_tops_and_are_worn(split_with_outfit, tmp_path, anny_body):
    data = DataConfig(split_dir=split_with_outfit, outfits=1, body_pool_size=2, validation_garments=1,
                      instances=str(tmp_path / "cache"), instance_count=4, validation_count=1, teacher_steps=4)
    templates = load_templates(data)
    assert [t.name for t in templates] == ["0000_tshirt", "0000_outfit", "0001_longsleeve"]  # held-out top last
    source = DrapeSource(data, model=SMALL, body=anny_body, templates=templates)
    manifest = json.loads((tmp_path / "cache" / "manifest.json").read_text())
    assert manifest["data"]["outfits"] == 1
    assert {r["garment"] for r in manifest["parts"]["val"]} == {2}
    drawn = [i for i, r in enumerate(manifest["parts"]["train"]) if r["garment"] == 1]
    assert drawn, "no cached instance of the outfit"
    seed = next(s for s in range(100) if int(np.random.default_rng(s).integers(4)) == drawn[0])
    sample = source.make_batch([seed])
    d = sample.drape
    assert d.cloth.grip is not None and d.cloth.layers is not None  # waistband gripped, layers kept
    terms = drape_energies(d.x_init, d.cloth, d.bodies, d.body_index, contact_stiffness=SMALL.contact_stiffness,
                           margin=SMALL.margin)
    assert "grip" in terms and "layer" in terms
    contact = dict(contact_stiffness=SMALL.contact_stiffness, margin=SMALL.margin)
    start = total_energy(d.x_init, d.cloth, d.bodies, d.body_index, **contact)
    assert (total_energy(sample.teacher, d.cloth, d.bodies, d.body_index, **contact) < start).all()


def test_one_piece_garment_is_worn_as_before(split_with_outfit, anny_body):
    pipeline = DrapePipeline(anny_body, dtype=torch.float32)
    top, outfit, _ = load_templates(DataConfig(split_dir=split_with_outfit, outfits=1, validation_garments=1))
    plain = pipeline.worn_job(top, 0, Material())
    assert plain.grip == 0.0 and not plain.layers
    worn = pipeline.worn_job(outfit, 0, Material())
    assert worn.grip > 0 and worn.layers

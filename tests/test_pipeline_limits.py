"""`DrapePipeline(x_init_limits=...)`: X_init's strain limiting other than the transfer's defaults;
what a pipeline keeps per garment template: the most recently used `TEMPLATES_KEPT`."""

from __future__ import annotations

import pytest
import torch

from physdrape.api.specs import garment_template
from physdrape.body.pool import BodyPool
from physdrape.body.skinning_transfer import SkinningTransfer
from physdrape.physics import Material
from physdrape import pipeline
from physdrape.pipeline import POSE_DTYPE, DrapePipeline, Job, PosedBodies


def test_x_init_limits_override_the_transfers_fields(anny_body):
    template = garment_template("default")
    state = BodyPool.from_seeds(anny_body, [5], dtype=POSE_DTYPE).state([0])
    plain, loose = DrapePipeline(anny_body), DrapePipeline(anny_body, x_init_limits={"min_stretch": None})
    assert plain.transfer(template).min_stretch == SkinningTransfer.min_stretch == 0.9
    assert loose.transfer(template).min_stretch is None
    assert loose.transfer(template).max_stretch == plain.transfer(template).max_stretch
    jobs = [Job(template, 0, Material())]
    bounded, skinned = (p.build(jobs, PosedBodies(state)).x_init for p in (plain, loose))
    assert not torch.equal(bounded, skinned)  # the bound moved compressed edges apart
    with pytest.raises(ValueError, match="unknown field"):
        DrapePipeline(anny_body, x_init_limits={"min_strech": 0.8})


def test_a_pipeline_keeps_the_data_of_its_most_recent_templates_and_derives_the_others_again(anny_body, monkeypatch):
    monkeypatch.setattr(pipeline, "TEMPLATES_KEPT", 2)
    templates = [garment_template(spec) for spec in ("tanktop:1", "croptop:2", "tanktop:3")]
    state = PosedBodies(BodyPool.from_seeds(anny_body, [5], dtype=POSE_DTYPE).state([0]))
    kept = DrapePipeline(anny_body)
    first = kept.build([Job(templates[0], 0, Material())], state)
    for template in templates[1:]:
        kept.build([Job(template, 0, Material())], state)
    for memo in (kept._transfers, kept._garments):
        assert len(memo) == 2 and templates[0].key not in memo and templates[2].key in memo
    again = kept.build([Job(templates[0], 0, Material())], state)  # let go, derived again: the same input
    assert templates[0].key in kept._transfers and templates[1].key not in kept._transfers
    assert torch.equal(again.x_init, first.x_init)
    assert torch.equal(again.garments.rest, first.garments.rest) and torch.equal(again.cloth.faces, first.cloth.faces)

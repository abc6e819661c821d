"""`DrapePipeline(x_init_limits=...)`: X_init's strain limiting other than the transfer's defaults."""

from __future__ import annotations

import pytest
import torch

from physdrape.api.specs import garment_template
from physdrape.body.pool import BodyPool
from physdrape.body.skinning_transfer import SkinningTransfer
from physdrape.physics import Material
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

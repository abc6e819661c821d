"""`DrapePipeline.build` on more than one torch thread: the X_inits of different bodies are made
in parallel, and they are the ones a single thread makes, bit for bit."""

from __future__ import annotations

import torch

from physdrape.api.specs import garment_template
from physdrape.body.pool import BodyPool
from physdrape.physics import Material
from physdrape.pipeline import POSE_DTYPE, DrapePipeline, Job, PosedBodies


def test_parallel_x_inits_equal_one_threads(anny_body, threads):
    template = garment_template("default")
    state = BodyPool.from_seeds(anny_body, [5, 6, 7], dtype=POSE_DTYPE).state([0, 1, 2])
    # two jobs on body 0 (they run in turn), one each on bodies 1 and 2 (in parallel)
    jobs = [Job(template, body, Material()) for body in (0, 1, 0, 2)]
    built = {}
    for count in (1, 2):
        threads(count)
        built[count] = DrapePipeline(anny_body).build(jobs, PosedBodies(state)).x_init
    assert torch.equal(built[1], built[2])
    num_verts = template.verts.shape[0]
    assert torch.equal(built[2][:num_verts], built[2][2 * num_verts:3 * num_verts])  # the same body twice
    assert not torch.equal(built[2][:num_verts], built[2][num_verts:2 * num_verts])

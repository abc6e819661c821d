"""`DrapePipeline.build`'s X_inits: on more than one torch thread those of different bodies are
made in parallel, on one thread those of a template on every body of the batch as one batch of
meshes, and both are the ones each job gets alone, bit for bit; on a GPU pipeline they are made on
the GPU."""

from __future__ import annotations

import numpy as np
import torch
from device_params import needs_cuda

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


@needs_cuda
def test_x_init_on_cuda_matches_the_cpus(anny_body):
    """On a GPU pipeline the garments are skinned and limited on the GPU, against the posed bodies'
    surfaces there; X_init agrees with the CPU's to well below a millimetre."""
    template = garment_template("default")
    state = BodyPool.from_seeds(anny_body, [5, 6], dtype=POSE_DTYPE).state([0, 1])
    jobs = [Job(template, body, Material()) for body in (0, 1)]
    on_cpu = DrapePipeline(anny_body).build(jobs, PosedBodies(state))
    posed = PosedBodies(state)
    on_gpu = DrapePipeline(anny_body, device="cuda").build(jobs, posed)
    assert on_gpu.x_init.device.type == "cuda"
    assert not any(key[-1].type == "cpu" for key in posed._surfaces if isinstance(key[-1], torch.device))
    torch.testing.assert_close(on_gpu.x_init.cpu(), on_cpu.x_init, rtol=0, atol=1e-4)
    # a garment sized to a body: its rest shape made on the GPU, from the posed bodies there
    np.testing.assert_allclose(DrapePipeline(anny_body, device="cuda").fitted_rest(template, posed, 1),
                               DrapePipeline(anny_body).fitted_rest(template, state, 1), rtol=0, atol=1e-9)

"""A batch draped on two torch threads splits between them by pose (`api.batch_threads`), a batch
larger than a CPU pack into packs, and each group's drapes are those of draping the group as a
batch of its own on one thread, bit for bit."""

from __future__ import annotations

import numpy as np
import torch

from physdrape.api import batch_threads
from physdrape.api.batch_threads import thread_groups


def test_split_batch_equals_its_groups_draped_alone(draper, threads):
    poses = [draper.poses(f"random:{k}")[0].pose[0] for k in (11, 12, 13)]
    batch = [poses[0], poses[1], poses[0], poses[2]]  # pose 0 twice: those two stay in one group
    threads(2)
    groups = thread_groups([_job(draper, p) for p in batch], draper.device, refine=False)
    assert groups == [[0, 2], [1, 3]]  # pose 0 (two garments) alone; poses 1 and 2 together
    split = draper.drape("default", pose=batch, batch_size=4)
    assert [r.timings["batch_size"] for r in split] == [2.0] * 4  # each result's timings: its group's
    threads(1)
    alone = {}
    for group in groups:
        for i, result in zip(group, draper.drape("default", pose=[batch[i] for i in group], batch_size=len(group))):
            alone[i] = result
    for i, result in enumerate(split):
        assert np.array_equal(result.verts, alone[i].verts), f"job {i}"
        assert result.metrics == alone[i].metrics
    assert not np.array_equal(split[0].verts, split[1].verts)
    assert np.array_equal(split[0].verts, split[2].verts)  # the same garment on the same pose


def test_a_batch_larger_than_a_pack_drapes_in_packs(draper, threads, monkeypatch):
    poses = [draper.poses(f"random:{k}")[0].pose[0] for k in (21, 22, 23)]
    threads(1)
    monkeypatch.setattr(batch_threads, "CPU_PACK_VERTICES", 2 * draper.garment("default").num_verts)
    groups = thread_groups([_job(draper, p) for p in poses], draper.device, refine=False)
    assert groups == [[0, 2], [1]]  # two packs (at most two T-shirts each), balanced
    packed = draper.drape("default", pose=poses, batch_size=3)
    assert [r.timings["batch_size"] for r in packed] == [2.0, 1.0, 2.0]
    for group in groups:
        alone = draper.drape("default", pose=[poses[i] for i in group], batch_size=len(group))
        for i, result in zip(group, alone):
            assert np.array_equal(packed[i].verts, result.verts), f"job {i}"


def test_no_split_with_one_pose_or_refinement(draper, threads):
    threads(2)
    job = _job(draper, draper.poses("stand")[0].pose[0])
    assert thread_groups([job, job, job], draper.device, refine=False) == [[0, 1, 2]]
    other = _job(draper, draper.poses("random:3")[0].pose[0])
    assert len(thread_groups([job, other], draper.device, refine=False)) == 2
    assert thread_groups([job, other], draper.device, refine=True) == [[0, 1]]
    assert thread_groups([job, other], torch.device("cuda"), refine=False) == [[0, 1]]


def _job(draper, pose: torch.Tensor):
    """A stand-in for the Draper's job: what `thread_groups` reads (the pose and the template)."""
    from physdrape.api.specs import BodyPose

    class Job:
        pass

    job = Job()
    job.pose = BodyPose("anny", pose[None], "test")
    job.template = draper.garment("default")
    return job

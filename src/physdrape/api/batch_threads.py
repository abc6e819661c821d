"""A batch of drapes split whole between CPU threads.

With several torch threads, torch runs each op of a drape on its shared pool, but a drape is
hundreds of small ops per solver step, each too small to gain much from a second thread. A batch
of garments on several poses splits instead into groups that drape side by side, one per thread,
each from posing its bodies to the metrics of its results, with its torch ops inline
(`threads.single_torch_thread`); Warp kernels and torch ops release the GIL. The jobs of one pose
stay in one group: they share that posed body and its surface, whose kept searches one thread at a
time may use. A group's results are those of draping it as a batch of its own.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from physdrape.threads import balanced_groups, parallel_map, single_torch_thread


def thread_groups(jobs: Sequence, device: torch.device, *, refine: bool) -> list[list[int]]:
    """The groups (job indices) a batch of jobs (each with `.pose` a `BodyPose` and `.template`)
    drapes in: one per torch thread on the CPU, the jobs of one pose (and body shape) together,
    balanced by vertex count; a single group on CUDA, with one torch thread, with one pose, or
    with the oracle's refinement (its sparse factorisations run on torch's pool)."""
    threads = torch.get_num_threads() if torch.device(device).type == "cpu" else 1
    if threads < 2 or refine or len(jobs) < 2:
        return [list(range(len(jobs)))]
    keys = [(job.pose.rig, job.pose.pose.cpu().numpy().tobytes(),
             None if job.pose.shape is None else job.pose.shape.cpu().numpy().tobytes()) for job in jobs]
    return balanced_groups(keys, [job.template.num_verts for job in jobs], threads)


def drape_groups(drape: Callable[[list], tuple[list, list]], jobs: Sequence, groups: list[list[int]]
                 ) -> tuple[list, list]:
    """drape(jobs of a group) → (results, carried) for every group on parallel threads, torch's
    own threads set to one meanwhile; the results and carried states in the order of `jobs`."""
    with single_torch_thread():
        outs = parallel_map(lambda group: drape([jobs[i] for i in group]), groups, "drape")
    results: list = [None] * len(jobs)
    carried: list = [None] * len(jobs)
    for group, (res, nxt) in zip(groups, outs):
        for k, i in enumerate(group):
            results[i], carried[i] = res[k], nxt[k]
    return results, carried

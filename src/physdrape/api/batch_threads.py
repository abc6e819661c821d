"""A batch of drapes split whole between CPU threads, and into packs the CPU's caches hold.

With several torch threads, torch runs each op of a drape on its shared pool, but a drape is
hundreds of small ops per solver step, each too small to gain much from a second thread. A batch
of garments on several poses splits instead into groups that drape side by side, one per thread,
each from posing its bodies to the metrics of its results, with its torch ops inline
(`threads.single_torch_thread`); Warp kernels and torch ops release the GIL. The jobs of one pose
stay in one group: they share that posed body and its surface, whose kept searches one thread at a
time may use. A group's results are those of draping it as a batch of its own.

On the CPU a group also holds at most about `CPU_PACK_VERTICES` garment vertices: a packed batch
much larger than that costs more per garment than the same garments in smaller packs one after
another (32 T-shirts in one pack against packs of 8; likely its per-vertex arrays outgrowing the
caches), so a large batch drapes as several groups, as many at a time as there are threads
(`bench/bench_scaling.py`'s batch rows time it).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch

from physdrape.threads import balanced_groups, parallel_map, single_torch_thread

#: Most garment vertices a group drapes in one packed batch on the CPU (about 8 garments of 3k
#: vertices; one garment larger than this is a group of its own).
CPU_PACK_VERTICES = 25_000


def thread_groups(jobs: Sequence, device: torch.device, *, refine: bool) -> list[list[int]]:
    """The groups (job indices) a batch of jobs (each with `.pose` a `BodyPose` and `.template`)
    drapes in, on the CPU: at least one per torch thread and as many as packs of at most
    `CPU_PACK_VERTICES` vertices need, the jobs of one pose (and body shape) together, balanced by
    vertex count; a single group on CUDA, with one pose, or with the oracle's refinement (its
    sparse factorisations run on torch's pool)."""
    on_cpu = torch.device(device).type == "cpu"
    sizes = [job.template.num_verts for job in jobs]
    parts = max(torch.get_num_threads(), -(-sum(sizes) // CPU_PACK_VERTICES)) if on_cpu else 1
    if parts < 2 or refine or len(jobs) < 2:
        return [list(range(len(jobs)))]
    keys = [(job.pose.rig, job.pose.pose.cpu().numpy().tobytes(),
             None if job.pose.shape is None else job.pose.shape.cpu().numpy().tobytes()) for job in jobs]
    return balanced_groups(keys, sizes, parts)


def drape_groups(drape: Callable[[list], tuple[list, list]], jobs: Sequence, groups: list[list[int]]
                 ) -> tuple[list, list]:
    """drape(jobs of a group) → (results, carried) for every group, as many at a time as torch has
    threads, torch's own threads set to one meanwhile; the results and carried states in the
    order of `jobs`."""
    workers = torch.get_num_threads()
    with single_torch_thread():
        outs = parallel_map(lambda group: drape([jobs[i] for i in group]), groups, "drape", workers)
    results: list = [None] * len(jobs)
    carried: list = [None] * len(jobs)
    for group, (res, nxt) in zip(groups, outs):
        for k, i in enumerate(group):
            results[i], carried[i] = res[k], nxt[k]
    return results, carried

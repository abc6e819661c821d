"""Draping a manifest at dataset scale: this process's share of the jobs, in batches, each job's
files written atomically into ``OUT/<id>/``, finished jobs skipped, failures recorded.

- Shards: job j (its `ManifestJob.index`) belongs to rank ``j % world_size``; each rank reads the
  whole manifest, drapes and writes only its own jobs, and needs no process group (torchrun's
  RANK and WORLD_SIZE, see `ranks_from_env`).
- Batches: `Draper.drape` takes one body shape and one garment unit per call, so jobs are grouped
  by (shape, units, rig) and each group is draped `batch_size` jobs per call (`batches`).
- Resume: a job folder appears whole or not at all (`physdrape.atomic.atomic_directory`). Its
  report.json records the job and the settings (`job_record`); a folder whose record matches and
  that holds every file of the chosen `Outputs` is complete and skipped (`job_state`).
- Failures: a batch that raises is retried job by job; a job that fails alone is recorded with
  its error and the run goes on. The summary of each rank (`summary_path`) is written atomically
  when the run ends, is interrupted or stops on an error.
"""

from __future__ import annotations

import json
import os
import shutil
import time
import warnings
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

from physdrape import __version__
from physdrape.api.manifest import RESERVED_PREFIX, Manifest, ManifestError, ManifestJob, check_rank, read_manifest
from physdrape.api.types import DrapeError, DrapeResult, DrapeWarning
from physdrape.atomic import atomic_directory
from physdrape.export import save_result, write_json
from physdrape.geometry.mesh import write_mesh
from physdrape.progress import progress_bar

#: The file every job folder holds; it records the job and the settings it was draped with.
REPORT = "report.json"
_MESHES = ("garment.obj", "garment.ply", "body.obj", "body.ply", "drape.glb")


class Outputs(Enum):
    """The files written per job: ``lean`` the draped garment (garment.ply, binary) and report.json;
    ``meshes`` also the posed body and the scene (what `DrapeResult.save` writes); ``full`` also
    render.png (what a single ``physdrape drape`` writes)."""

    LEAN = "lean"
    MESHES = "meshes"
    FULL = "full"

    @property
    def files(self) -> tuple[str, ...]:
        own = {"lean": ("garment.ply",), "meshes": _MESHES, "full": (*_MESHES, "render.png")}[self.value]
        return (*own, REPORT)


@dataclass
class ManifestSummary:
    """What one rank did with its share of a manifest (written to `summary_path` as JSON).

    jobs: the rank's valid jobs; done: ids draped by this run; skipped: ids complete before it;
    failed: {"id", "line", "error"} per job that failed; bad_lines: {"line", "error"} per bad line
    of this rank's share that was skipped; status: "running", "complete" or "interrupted" (stopped
    by Ctrl-C or an error: rerun the same command to go on).
    """

    manifest: str
    out: str
    rank: int
    world_size: int
    outputs: str
    jobs: int
    done: list[str] = field(default_factory=list)
    skipped: list[str] = field(default_factory=list)
    failed: list[dict[str, Any]] = field(default_factory=list)
    bad_lines: list[dict[str, Any]] = field(default_factory=list)
    status: str = "running"
    wall_time_s: float = 0.0


def ranks_from_env(environ: Mapping[str, str] | None = None) -> tuple[int, int]:
    """(rank, world size) from RANK and WORLD_SIZE (as torchrun sets them); (0, 1) when neither is set."""
    env = os.environ if environ is None else environ
    if "RANK" not in env and "WORLD_SIZE" not in env:
        return 0, 1
    try:
        rank, world_size = int(env.get("RANK", "")), int(env.get("WORLD_SIZE", ""))
    except ValueError:
        raise DrapeError(f"RANK={env.get('RANK')!r} and WORLD_SIZE={env.get('WORLD_SIZE')!r}: set both to integers, "
                         "0 <= RANK < WORLD_SIZE (torchrun sets them), or neither") from None
    check_rank(rank, world_size)
    return rank, world_size


def summary_path(out: str | Path, rank: int, world_size: int) -> Path:
    """The summary file of `rank` among `world_size` in `out`."""
    return Path(out) / f"{RESERVED_PREFIX}rank{rank}-of-{world_size}.json"


#: Settings the record gained later, and the value every drape made before had: a report without
#: the key counts as made with it.
RECORD_DEFAULTS = {"passes": 1}


def job_record(draper, job: ManifestJob, *, refine: bool) -> dict[str, Any]:
    """What a job folder's report.json must hold to count as this job's drape: the line's job and
    the settings that change the drape (model, network passes, solver steps, refine, body,
    garment unit)."""
    return {"job": job.spec, "checkpoint": str(Path(draper.checkpoint).resolve()),
            "passes": draper.model_config.passes, "steps": draper.steps, "refine": bool(refine),
            "body": "anny" if draper.smpl is None else "smpl", "units": job.units}


def job_state(folder: Path, record: Mapping[str, Any], outputs: Outputs) -> str:
    """"missing" (no folder), "complete" (the record matches and every file of `outputs` is
    there), "incomplete" (the record matches, some files of `outputs` are not there: an earlier
    run wrote fewer) or "stale" (the folder holds another job's drape, other settings, or files
    that are no job's output; `stale_reason` says which)."""
    if not folder.is_dir():
        return "missing"
    if stale_reason(folder, record):
        return "stale"
    return "complete" if all((folder / name).is_file() for name in outputs.files) else "incomplete"


def stale_reason(folder: Path, record: Mapping[str, Any]) -> str | None:
    """Why the job folder `folder` is not a drape of `record` (e.g. "its steps is 2, not 3"), or None."""
    try:
        report = json.loads((folder / REPORT).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return f"no readable {REPORT}, so no job's output"
    if not isinstance(report, dict):
        return f"its {REPORT} is not a job's report"
    if report.get("job") != record["job"]:
        return "it holds another job (the line changed, or another manifest used this id)"
    for key, value in record.items():
        if report.get(key, RECORD_DEFAULTS.get(key)) != value:
            return f"its {key} is {report.get(key, RECORD_DEFAULTS.get(key))!r}, not {value!r}"
    return None


def batches(jobs: Iterable[ManifestJob], batch_size: int) -> Iterator[list[ManifestJob]]:
    """Jobs grouped so that each group is one `Draper.drape` call: the same shape, garment unit
    and rig, at most `batch_size` jobs. A group is yielded as soon as it is full, the others in
    order of their first job at the end."""
    if batch_size < 1:
        raise DrapeError(f"batch_size must be >= 1, got {batch_size}")
    groups: dict[tuple[str, str, str], list[ManifestJob]] = {}
    for job in jobs:
        key = (json.dumps(job.shape, sort_keys=True), job.units, job.rig)
        group = groups.setdefault(key, [])
        group.append(job)
        if len(group) == batch_size:
            yield groups.pop(key)
    yield from groups.values()


def drape_jobs(draper, jobs: list[ManifestJob], *, refine: bool = False,
               allow_detached: bool = False) -> tuple[list[DrapeResult], list[str]]:
    """Drape a group from `batches` in one `Draper.drape` call: the results in order, and the
    `DrapeWarning`s the Draper gave (other warnings are shown as usual)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DrapeWarning)
        results = draper.drape([j.garment for j in jobs], shape=jobs[0].shape, pose=[j.pose for j in jobs],
                               material=[j.material for j in jobs], refine=refine, units=jobs[0].units,
                               batch_size=len(jobs), allow_detached=allow_detached)
    for w in caught:
        if not issubclass(w.category, DrapeWarning):
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
    return results, list(dict.fromkeys(str(w.message) for w in caught if issubclass(w.category, DrapeWarning)))


def write_job(out: Path, job: ManifestJob, result: DrapeResult, record: Mapping[str, Any], outputs: Outputs, *,
              notes: Iterable[str] = (), render_size: int = 640) -> Path:
    """Write one job's files into ``out/<id>/`` as a whole (a temporary folder beside it, renamed
    into place; an earlier folder of that name is replaced)."""
    start = time.perf_counter()
    folder = out / job.id
    with atomic_directory(folder) as tmp:
        if outputs is Outputs.LEAN:
            write_mesh(tmp / "garment.ply", result.verts, result.faces)
        else:
            save_result(result, tmp)
        if outputs is Outputs.FULL:
            from physdrape.render import render_result

            render_result(result, tmp / "render.png", size=render_size)
        entry = result.report()
        entry["directory"] = "."
        wall = result.timings.get("per_garment_s", 0.0) + time.perf_counter() - start
        write_json(tmp / REPORT, {**record, "id": job.id, "line": job.line, "physdrape_version": __version__,
                                  "shape": job.shape, "outputs": list(outputs.files), "warnings": list(notes),
                                  "num_results": 1, "wall_time_s": wall, "results": [entry]})
    return folder


def run_manifest(draper, manifest: Manifest | str | Path, out: str | Path, *, rank: int = 0, world_size: int = 1,
                 outputs: Outputs | str = Outputs.LEAN, batch_size: int = 8, refine: bool = False,
                 allow_detached: bool = False, skip_bad_lines: bool = False, force: bool = False,
                 progress: bool = False, render_size: int = 640, units: str = "m") -> ManifestSummary:
    """Drape rank `rank`'s share of a manifest into `out` (see the module's docstring).

    Args:
        draper: the `Draper` (its checkpoint, steps and body are recorded with every job).
        manifest: a `Manifest` or the path of one (read with `units` as the default garment unit).
        out: the folder of the job folders and the summaries; created if needed.
        rank, world_size: this process's place among the processes sharing the manifest.
        outputs: the files per job (`Outputs`, or its value "lean", "meshes", "full").
        batch_size: jobs per `Draper.drape` call (jobs of one call share shape, unit and rig).
        refine, allow_detached: as in `Draper.drape`.
        skip_bad_lines: drape the valid jobs and list the bad lines in the summary; else a
            manifest with bad lines raises `ManifestError` before anything is draped.
        force: replace job folders that hold another drape (the line changed, or the model,
            steps, refine or body differ); else their presence raises DrapeError before anything
            is draped.
        progress: a tqdm bar on stderr over this rank's jobs.

    Returns:
        the `ManifestSummary`, also written to `summary_path(out, rank, world_size)`.
    """
    start = time.perf_counter()
    outputs = Outputs(outputs)
    if not isinstance(manifest, Manifest):
        manifest = read_manifest(manifest, smpl=draper.smpl is not None, units=units)
    if manifest.bad and not skip_bad_lines:
        raise ManifestError(manifest.path, manifest.bad)
    if batch_size < 1:
        raise DrapeError(f"batch_size must be >= 1, got {batch_size}")
    mine = manifest.shard(rank, world_size)
    out = Path(out).expanduser()
    if out.exists() and not out.is_dir():
        raise DrapeError(f"output folder {out} exists and is not a folder; choose another")
    records = {job.id: job_record(draper, job, refine=refine) for job in mine.jobs}
    states = {job.id: job_state(out / job.id, records[job.id], outputs) for job in mine.jobs}
    stale = [job for job in mine.jobs if states[job.id] == "stale"]
    if stale and not force:
        listed = "; ".join(f"{out / j.id} (line {j.line}): {stale_reason(out / j.id, records[j.id])}"
                           for j in stale[:3])
        more = f"; and {len(stale) - 3} more" if len(stale) > 3 else ""
        raise DrapeError(f"{len(stale)} job folder(s) hold another drape or other files: {listed}{more}. Pass "
                         "--force (API force=True) to drape them again and replace them, or choose another --out")
    out.mkdir(parents=True, exist_ok=True)
    _remove_leftovers(out, set(records))
    summary = ManifestSummary(str(manifest.path.resolve()), str(out.resolve()), rank, world_size, outputs.value,
                              len(mine.jobs), bad_lines=[{"line": b.line, "error": b.error} for b in mine.bad])
    summary.skipped = [job.id for job in mine.jobs if states[job.id] == "complete"]
    pending = [job for job in mine.jobs if states[job.id] != "complete"]
    bar = _bar(progress, len(mine.jobs), len(summary.skipped), rank, world_size)
    try:
        for group in batches(pending, batch_size):
            for job, outcome, notes in _drape_group(draper, group, refine=refine, allow_detached=allow_detached):
                if isinstance(outcome, DrapeResult):
                    write_job(out, job, outcome, records[job.id], outputs, notes=notes, render_size=render_size)
                    summary.done.append(job.id)
                else:
                    summary.failed.append({"id": job.id, "line": job.line, "error": outcome})
                if bar is not None:
                    bar.update(1)
                    if summary.failed:
                        bar.set_postfix(failed=len(summary.failed), refresh=False)
    except BaseException:
        summary.status = "interrupted"
        raise
    else:
        summary.status = "complete"
    finally:
        if bar is not None:
            bar.close()
        summary.wall_time_s = time.perf_counter() - start
        write_json(summary_path(out, rank, world_size), asdict(summary))
    return summary


def _drape_group(draper, group: list[ManifestJob], *, refine: bool,
                 allow_detached: bool) -> Iterator[tuple[ManifestJob, DrapeResult | str, list[str]]]:
    """(job, result or error message, notes) per job of `group`: the group in one call, or, when
    that raises, job by job (so that one bad job does not fail the others)."""
    try:
        results, caught = drape_jobs(draper, group, refine=refine, allow_detached=allow_detached)
    except Exception as exc:  # noqa: BLE001 - any failure of a job is recorded, and the run goes on
        if len(group) == 1:
            message = str(exc) if isinstance(exc, DrapeError) else f"{type(exc).__name__}: {exc}"
            yield group[0], message, []
            return
        for job in group:
            yield from _drape_group(draper, [job], refine=refine, allow_detached=allow_detached)
        return
    for job, result in zip(group, results):
        own = [w for w in caught if result.name in w] if len(group) > 1 else caught
        yield job, result, [*job.notes, *own]


def _remove_leftovers(out: Path, ids: set[str]) -> None:
    """Remove the temporary folders of these jobs that a killed run left in `out` (hidden
    ``.<id>.<random>`` folders beside the job folders; see `physdrape.atomic`)."""
    for entry in os.scandir(out):
        own = entry.name.startswith(".") and entry.name[1:].rpartition(".")[0] in ids
        if own and entry.is_dir(follow_symlinks=False):
            shutil.rmtree(entry.path, ignore_errors=True)


def _bar(progress: bool, total: int, initial: int, rank: int, world_size: int):
    if not progress:
        return None
    desc = "draping" if world_size == 1 else f"rank {rank}/{world_size}"
    return progress_bar(total=total, initial=initial, unit="job", desc=desc)

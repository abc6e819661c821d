"""`physdrape drape --manifest`: flags, bad lines, resume, Ctrl-C, and two torchrun processes
sharing one manifest, on the tiny test model."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from physdrape.cli import main

FAST = ["--steps", "2", "--no-progress"]


def _write(path: Path, lines: list) -> Path:
    path.write_text("".join((line if isinstance(line, str) else json.dumps(line)) + "\n" for line in lines))
    return path


@pytest.fixture
def run(tiny_checkpoint, anny_body):
    """`physdrape drape --manifest` in this process on the tiny model."""
    def run(manifest: Path, out: Path, *flags: str) -> int:
        return main(["drape", "--manifest", str(manifest), "--out", str(out), "--checkpoint", tiny_checkpoint,
                     *FAST, *flags])

    return run


def test_single_drape_flags_are_refused_with_the_job_key_to_use(run, tmp_path, capsys):
    jobs = _write(tmp_path / "jobs.jsonl", [{"id": "a"}])
    assert run(jobs, tmp_path / "out", "--pose", "stand") == 2
    assert 'give "pose" in each line of the manifest' in capsys.readouterr().err
    assert run(jobs, tmp_path / "out", "--figures") == 2
    assert "not available with --manifest" in capsys.readouterr().err
    assert run(jobs, tmp_path / "out", "--seed", "0") == 2
    assert 'give "garment" in each line' in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_bad_lines_stop_before_draping_or_are_skipped_and_listed(run, tmp_path, capsys):
    jobs = _write(tmp_path / "jobs.jsonl", [{"id": "a"}, {"pose": "jump"}, "{", {"id": "b", "material": "wool"}])
    assert run(jobs, tmp_path / "out") == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "3 bad line(s), nothing draped" in err
    assert "line 2: unknown pose 'jump'" in err and "line 3: not JSON" in err and "line 4: material preset" in err
    assert "--skip-bad-lines" in err and not (tmp_path / "out").exists()
    assert run(jobs, tmp_path / "out", "--skip-bad-lines") == 0
    captured = capsys.readouterr()
    listed = [line for line in captured.err.splitlines() if line.startswith("physdrape: skipped bad line")]
    assert [line.split(" of ")[0][-1] for line in listed] == ["2", "3", "4"]
    assert "1 job(s) draped" in captured.out and "3 bad line(s) skipped" in captured.out
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a", "summary.rank0-of-1.json"]


def test_rerun_drapes_only_the_missing_jobs(run, tmp_path, capsys, monkeypatch):
    jobs = _write(tmp_path / "jobs.jsonl", [{"id": "a"}, {"id": "b", "pose": "stand"}])
    out = tmp_path / "out"
    assert run(jobs, out) == 0
    assert "2 job(s) draped, 0 already done" in capsys.readouterr().out
    _write(jobs, [{"id": "a"}, {"id": "b", "pose": "stand"}, {"id": "c", "material": "silk"}])
    stamps = {name: (out / name / "garment.ply").stat().st_mtime_ns for name in ("a", "b")}
    assert run(jobs, out, "--outputs", "lean") == 0
    assert "1 job(s) draped, 2 already done" in capsys.readouterr().out
    assert {name: (out / name / "garment.ply").stat().st_mtime_ns for name in ("a", "b")} == stamps
    summary = json.loads((out / "summary.rank0-of-1.json").read_text())
    assert (summary["done"], summary["skipped"], summary["status"]) == (["c"], ["a", "b"], "complete")

    import physdrape.api.draper

    def interrupt(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(physdrape.api.draper.Draper, "drape", interrupt)
    _write(jobs, [{"id": "d"}])
    assert run(jobs, out) == 130
    err = capsys.readouterr().err
    assert err.startswith("physdrape: interrupted; the finished jobs are in") and "run the same command again" in err
    assert not (out / "d").exists() and not [p for p in out.iterdir() if p.name.startswith(".")]


def test_two_torchrun_processes_write_each_job_exactly_once(tiny_checkpoint, tmp_path):
    ids = [f"job{k}" for k in range(5)]
    jobs = _write(tmp_path / "jobs.jsonl", [{"id": i, "pose": p} for i, p in zip(ids, ["stand", "t-pose"] * 3)])
    out = tmp_path / "out"
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    for name in ("RANK", "WORLD_SIZE", "LOCAL_RANK", "MASTER_ADDR", "MASTER_PORT"):
        env.pop(name, None)
    command = [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc-per-node", "2",
               "-m", "physdrape.cli", "drape", "--manifest", str(jobs), "--out", str(out),
               "--checkpoint", tiny_checkpoint, "--batch-size", "2", *FAST]
    done = subprocess.run(command, check=False, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    summaries = [json.loads((out / f"summary.rank{r}-of-2.json").read_text()) for r in range(2)]
    for rank, summary in enumerate(summaries):
        assert summary["status"] == "complete" and summary["failed"] == [] and summary["skipped"] == []
        assert sorted(summary["done"]) == ids[rank::2]  # job j on rank j mod 2
    assert sorted(p.name for p in out.iterdir() if p.is_dir()) == ids
    for i in ids:
        report = json.loads((out / i / "report.json").read_text())
        assert report["id"] == i and report["job"]["id"] == i
    assert "rank 0/2: 3 job(s) draped" in done.stdout and "rank 1/2: 2 job(s) draped" in done.stdout

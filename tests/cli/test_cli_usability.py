"""What a newcomer meets on the command line: Ctrl-C, --force, report.json's documentation,
--units and detached garments (tiny test model, fast flags)."""

from __future__ import annotations

import json
import os
import re
import signal
from pathlib import Path

import numpy as np
import pytest
import torch

from physdrape import checkpoint
from physdrape.cli import main
from physdrape.cli.common import deferred_interrupt

FAST = ["--steps", "2", "--render-size", "48"]
REPORT_DOC = Path(__file__).resolve().parents[2] / "docs" / "report.md"
SINGLE = {"garment.obj", "garment.ply", "body.obj", "body.ply", "drape.glb", "render.png", "report.json"}


@pytest.fixture
def bundled(tiny_checkpoint, anny_body, monkeypatch):
    """Make the tiny model the 'bundled' one."""
    monkeypatch.setattr(checkpoint, "bundled_model", lambda: Path(tiny_checkpoint))
    return tiny_checkpoint


@pytest.fixture(scope="module")
def tee(tmp_path_factory) -> tuple[np.ndarray, np.ndarray, Path]:
    """The bundled T-shirt as arrays and as an .obj in metres."""
    from physdrape.garments import default_garment
    from physdrape.geometry.mesh import write_mesh

    g = default_garment()
    path = tmp_path_factory.mktemp("garments") / "tee.obj"
    write_mesh(path, g.verts, g.faces)
    return np.asarray(g.verts, np.float64), np.asarray(g.faces, np.int64), path


def _write(path: Path, verts, faces) -> str:
    from physdrape.geometry.mesh import write_mesh

    write_mesh(path, verts, faces)
    return str(path)


def _leftovers(folder: Path) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(".")]


def _raise_interrupt(*args, **kwargs):
    raise KeyboardInterrupt


# ---------------------------------------------------------------------------- Ctrl-C
COMMANDS = {
    "drape": ("physdrape.api.draper.Draper.drape", ["drape", *FAST, "--out", "{out}"], "nothing was written to"),
    "fit": ("physdrape.api.fit_garment", ["fit", "{garment}", "--out", "{out}.obj"], "nothing was written to"),
    "train": ("physdrape.config_io.load_config", ["train", "--config", "c.yaml", "--run-dir", "{out}"],
              "resume with: physdrape train --config c.yaml --run-dir {out} --resume"),
    "eval": ("physdrape.eval.evaluate.evaluate", ["eval", "--checkpoint", "ck", "--out", "{out}", "--no-oracle"],
             "nothing was written to"),
}


@pytest.mark.parametrize("command", list(COMMANDS))
def test_ctrl_c_exits_130_with_one_line_and_no_output(bundled, tee, tmp_path, monkeypatch, capsys, command):
    target, argv, note = COMMANDS[command]
    monkeypatch.setattr(target, _raise_interrupt)
    out = tmp_path / "out"
    argv = [a.format(out=out, garment=tee[2]) for a in argv]
    assert main(argv) == 130
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    assert lines[0].startswith("physdrape: interrupted; ") and note.format(out=out) in lines[0]
    assert not out.exists() and not Path(f"{out}.obj").exists()
    assert not _leftovers(tmp_path)


def test_ctrl_c_while_writing_leaves_no_partial_output(bundled, tmp_path, monkeypatch, capsys):
    import physdrape.render

    out = tmp_path / "new" / "out"
    monkeypatch.setattr(physdrape.render, "render_result", _raise_interrupt)  # after the meshes were saved
    assert main(["drape", *FAST, "--out", str(out)]) == 130
    assert capsys.readouterr().err == f"physdrape: interrupted; nothing was written to {out}\n"
    assert not (tmp_path / "new").exists()  # nor the parent folder it created for --out


def test_ctrl_c_while_moving_the_output_in_place_is_held_back():
    before = signal.getsignal(signal.SIGINT)  # Python's default, or ignored in a background job
    with pytest.raises(KeyboardInterrupt, match="written in full"):
        with deferred_interrupt("OUT was written in full before stopping"):
            os.kill(os.getpid(), signal.SIGINT)
            finished = True  # the block ran to its end despite the Ctrl-C
    assert finished and signal.getsignal(signal.SIGINT) is before


# ---------------------------------------------------------------------------- --force
def test_force_replaces_the_output_folder_as_a_whole(bundled, tee, tmp_path, monkeypatch):
    out = tmp_path / "out"
    assert main(["drape", "--garment", "default", "--garment", str(tee[2]), "--figures", "--out", str(out),
                 *FAST]) == 0
    before = {p.name for p in out.iterdir()}
    assert {"gallery.png", "materials.png", "report.json"} < before and len(before) == 5  # 2 sub-folders
    assert main(["drape", "--out", str(out), *FAST]) == 2  # not without --force
    assert {p.name for p in out.iterdir()} == before

    import physdrape.render

    real = physdrape.render.render_result
    monkeypatch.setattr(physdrape.render, "render_result", _raise_interrupt)
    assert main(["drape", "--out", str(out), "--force", *FAST]) == 130  # an interrupted --force keeps the old run
    assert {p.name for p in out.iterdir()} == before
    monkeypatch.setattr(physdrape.render, "render_result", real)

    assert main(["drape", "--out", str(out), "--force", *FAST]) == 0
    assert {p.name for p in out.iterdir()} == SINGLE  # only the new run's files
    assert json.loads((out / "report.json").read_text())["num_results"] == 1
    assert not _leftovers(tmp_path)


def test_force_replaces_only_an_earlier_runs_folder(bundled, tmp_path, monkeypatch, capsys):
    other = tmp_path / "notes"
    other.mkdir()
    (other / "thesis.tex").write_text("x")
    assert main(["drape", "--out", str(other), "--force", *FAST]) == 2
    assert "no report.json" in capsys.readouterr().err and (other / "thesis.tex").is_file()
    (other / "report.json").write_text("{}")
    monkeypatch.chdir(other)
    assert main(["drape", "--out", ".", "--force", *FAST]) == 2
    assert "holds the current directory" in capsys.readouterr().err and (other / "thesis.tex").is_file()


# ---------------------------------------------------------------------------- report.json
def _keys(report: dict) -> set[str]:
    keys = set(report)
    for entry in report["results"]:
        keys |= set(entry) | set(entry["material"]) | set(entry["timings_s"])
    return keys


def test_every_report_field_is_documented(bundled, tmp_path):
    out = tmp_path / "out"
    assert main(["drape", "--shape", "weight=0.7", "--out", str(out), *FAST]) == 0
    report = json.loads((out / "report.json").read_text())
    documented = set(re.findall(r"`([A-Za-z_][A-Za-z0-9_]*)`", REPORT_DOC.read_text()))
    missing = sorted(_keys(report) - documented)
    assert not missing, f"report.json fields not in docs/report.md: {missing}"
    assert "residual_relative" in documented and "m_i·g" in REPORT_DOC.read_text()


# ---------------------------------------------------------------------------- --units
def test_a_centimetre_garment_drapes_with_units_cm_like_the_metre_one(bundled, tee, tmp_path, capsys):
    verts, faces, metre_file = tee
    cm_file = _write(tmp_path / "tee_cm.obj", verts * 100.0, faces)
    assert main(["drape", "--garment", cm_file, "--out", str(tmp_path / "bad"), *FAST]) == 2
    err = capsys.readouterr().err
    assert "looks like centimetres" in err and "--units cm" in err and not (tmp_path / "bad").exists()

    from physdrape.geometry.mesh import read_mesh

    assert main(["drape", "--garment", cm_file, "--units", "cm", "--out", str(tmp_path / "cm"), *FAST]) == 0
    assert main(["drape", "--garment", str(metre_file), "--out", str(tmp_path / "m"), *FAST]) == 0
    cm_verts, _ = read_mesh(tmp_path / "cm" / "garment.ply")
    m_verts, _ = read_mesh(tmp_path / "m" / "garment.ply")
    np.testing.assert_allclose(cm_verts, m_verts, atol=1e-5)  # outputs are in metres
    assert json.loads((tmp_path / "cm" / "report.json").read_text())["units"] == "cm"


def test_fit_reads_a_decimetre_garment_with_units_dm(anny_body, tee, tmp_path, capsys):
    from physdrape.geometry.mesh import read_mesh

    verts, faces, _ = tee
    dm_file = _write(tmp_path / "tee_dm.obj", verts * 10.0, faces)
    out = tmp_path / "fitted.obj"
    assert main(["fit", dm_file, "--out", str(out), "--scale", "0.1", "--iters", "0"]) == 2
    assert "--units dm" in capsys.readouterr().err  # a unit conversion is not a fitting scale
    assert main(["fit", dm_file, "--out", str(out), "--iters", "0"]) == 2
    assert "--units dm" in capsys.readouterr().err
    assert main(["fit", dm_file, "--units", "dm", "--out", str(out), "--iters", "0"]) == 0
    fitted, _ = read_mesh(out)
    assert np.abs(fitted - verts).mean() < 0.01  # in metres, on the body


# ---------------------------------------------------------------------------- detached garments
def test_a_detached_garment_is_refused_unless_allowed(bundled, tmp_path, capsys):
    corner = np.array([0.3, -0.05, 0.3])  # 12 cm in front of and beside the left hip
    triangle = _write(tmp_path / "triangle.obj", corner + [[0.0, 0.0, 0.0], [0.1, 0.0, 0.0], [0.0, 0.1, 0.0]],
                      [[0, 1, 2]])
    out = tmp_path / "out"
    assert main(["drape", "--garment", triangle, "--out", str(out), *FAST]) == 2
    err = capsys.readouterr().err
    assert err.startswith("physdrape: error: garment 'triangle' neither touches nor surrounds the body")
    assert "--allow-detached" in err and "metres" in err and not out.exists()

    grid = np.linspace(0.0, 0.1, 3)  # a 10 cm square of 8 triangles in its place
    square = [[a, a + 1, a + 3] for a in (0, 1, 3, 4)] + [[a + 1, a + 4, a + 3] for a in (0, 1, 3, 4)]
    patch = _write(tmp_path / "patch.obj", corner + np.array([[x, y, 0.0] for y in grid for x in grid]), square)
    assert main(["drape", "--garment", patch, "--allow-detached", "--out", str(out), *FAST]) == 0
    warnings = [line for line in capsys.readouterr().err.splitlines() if line.startswith("physdrape: warning:")]
    assert len(warnings) == 1 and "neither touches nor surrounds" in warnings[0]
    assert json.loads((out / "report.json").read_text())["warnings"] == [warnings[0][len("physdrape: warning: "):]]


@pytest.mark.skipif(torch.cuda.is_available(), reason="checks the message on a machine without CUDA")
def test_asking_for_cuda_without_a_gpu_says_how_to_fix_it(tmp_path, capsys):
    assert main(["drape", "--device", "cuda", "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("physdrape: error: device 'cuda' asks for CUDA") and "device='cpu'" in err
    assert not (tmp_path / "out").exists()


def test_cuda_under_torchrun_means_the_local_ranks_gpu(monkeypatch):
    from physdrape.cli.common import process_device

    monkeypatch.setenv("LOCAL_RANK", "3")
    assert process_device("cuda") == "cuda:3" and process_device("cpu") == "cpu" and process_device("cuda:1") == "cuda:1"

"""`physdrape drape --smpl-model ...` on a synthetic model in SMPL's file layout: β, θ, AMASS frames
(warm-started), and every bad-input path (exit 2, a message naming the problem and the fix)."""

from __future__ import annotations

import json
import re

import numpy as np
import pytest

from physdrape.cli import main

from smpl_helpers import write_amass, write_synthetic_smpl, write_torso_band

pytest.importorskip("smplx")
FAST = ["--steps", "2", "--render-size", "48"]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    d = tmp_path_factory.mktemp("smpl_cli")
    np.save(d / "theta.npy", 0.05 * np.ones((24, 3)))
    np.save(d / "theta_bad.npy", np.zeros((23, 3)))
    return {"model": write_synthetic_smpl(d / "SMPL_NEUTRAL.npz"), "band": write_torso_band(d / "band.obj"),
            "amass": write_amass(d / "seq.npz", frames=4), "theta": d / "theta.npy",
            "theta_bad": d / "theta_bad.npy", "dir": d}


def _base(files, tiny_checkpoint) -> list[str]:
    return ["drape", "--checkpoint", tiny_checkpoint, "--smpl-model", str(files["model"]), *FAST]


def test_smpl_betas_theta(files, tiny_checkpoint, tmp_path):
    out = tmp_path / "o"
    args = _base(files, tiny_checkpoint) + ["--garment", str(files["band"]), "--betas", "1.0,-0.5",
                                            "--theta", str(files["theta"]), "--out", str(out)]
    assert main(args) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["body"] == "smpl" and report["shape"] == {"betas": [1.0, -0.5]}
    [entry] = report["results"]
    assert entry["pose"] == "theta[0]" and np.isfinite(entry["E_strain_J"])
    assert (out / "garment.obj").is_file() and (out / "render.png").is_file()


def test_smpl_amass_frames_warm(files, tiny_checkpoint, tmp_path):
    out = tmp_path / "seq"
    args = _base(files, tiny_checkpoint) + ["--garment", str(files["band"]), "--amass", str(files["amass"]),
                                            "--frames", "1:4", "--out", str(out)]
    assert main(args) == 0
    results = json.loads((out / "report.json").read_text())["results"]
    assert [e["pose"] for e in results] == ["seq.npz#1", "seq.npz#2", "seq.npz#3"]
    assert [e["init"] for e in results] == ["skinning", "warm", "warm"]
    assert main(args[:-2] + ["--out", str(tmp_path / "model"), "--warm-start", "model"]) == 0
    model = json.loads((tmp_path / "model" / "report.json").read_text())["results"]
    assert [e["init"] for e in model] == ["skinning", "warm", "warm"]
    assert main(args[:-2] + ["--out", str(tmp_path / "bad"), "--warm-start", "model", "--no-warm-start"]) == 2
    assert main(args[:-2] + ["--out", str(tmp_path / "cold"), "--no-warm-start"]) == 0
    cold = json.loads((tmp_path / "cold" / "report.json").read_text())["results"]
    assert {e["init"] for e in cold} == {"skinning"}


BAD = [
    (["--garment", "@band", "--betas", "1,x"], "--betas: 'x' is not a number"),
    (["--garment", "@band", "--betas", "nan"], "not finite"),
    (["--garment", "@band", "--betas", ",".join(["0.1"] * 11)], "give 1..10 values"),
    (["--garment", "@band", "--shape", "weight=0.3"], "shaped by --betas"),
    ([], "give --garment FILE.*authored on SMPL's canonical body"),
    (["--garment", "default"], "made for the Anny body"),
    (["--garment", "@band", "--category", "tshirt"], "do not fit SMPL"),
    (["--garment", "@band", "--pose", "stand"], "presets are Anny poses"),
    (["--garment", "@band", "--bvh", "walk.bvh"], "retargets onto Anny only"),
    (["--garment", "@band", "--theta", "@theta_bad"], r"shape \(24, 3\) or \(72,\).*got \(23, 3\)"),
    (["--garment", "@band", "--theta", "no/such.npy"], "--theta no/such.npy: no such file"),
    (["--garment", "@band", "--theta", "@band"], "cannot read it as a .npy"),
    (["--garment", "@band", "--amass", "@band"], "takes AMASS .npz frames"),
    (["--garment", "@band", "--amass", "@amass", "--frames", "2:9"], "out of range: seq.npz has 4 frames"),
    (["--garment", "@band", "--amass", "@amass", "--frame", "4"], "out of range"),
    (["--garment", "@band", "--amass", "@noposes"], "missing 'poses'"),
    (["--garment", "@band", "--frames", "0:2"], "give --amass FILE.npz"),
    (["--garment", "@band", "--amass", "@amass", "--theta", "@theta"], "either --theta or --amass"),
]


@pytest.mark.parametrize(("flags", "pattern"), BAD, ids=[" ".join(f) or "no garment" for f, _ in BAD])
def test_smpl_bad_input_exits_2(files, tiny_checkpoint, tmp_path, capsys, flags, pattern):
    if any(f == "@noposes" for f in flags):
        files = dict(files, noposes=write_amass(tmp_path / "noposes.npz", poses=None))
    flags = [str(files[f[1:]]) if f.startswith("@") else f for f in flags]
    out = tmp_path / "out"
    assert main(_base(files, tiny_checkpoint) + flags + ["--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("physdrape: error:") and "Traceback" not in err
    assert re.search(pattern, err), err
    assert not out.exists()


@pytest.mark.parametrize(
    ("flags", "pattern"),
    [
        (["--smpl-model", "@missing"], "not found.*not shipped"),
        (["--betas", "1"], "give --smpl-model FILE"),
        (["--amass", "@amass"], "give --smpl-model FILE"),
    ],
)
def test_smpl_flags_need_a_model(files, tiny_checkpoint, tmp_path, capsys, flags, pattern):
    files = dict(files, missing=tmp_path / "SMPL_NEUTRAL.npz")
    flags = [str(files[f[1:]]) if f.startswith("@") else f for f in flags]
    assert main(["drape", "--checkpoint", tiny_checkpoint, "--garment", str(files["band"]), *flags,
                 "--out", str(tmp_path / "o")]) == 2
    assert re.search(pattern, capsys.readouterr().err)

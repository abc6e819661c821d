"""The `physdrape` command line. It calls only the public API (`physdrape.api`) and the library's
functions. Bad input exits with code 2 and a one-line message on stderr; no traceback."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import torch

from physdrape.api import DrapeError
from physdrape.config_io import ConfigError
from physdrape.geometry.mesh import MeshError
from physdrape.train.checkpoint import CheckpointError

# ----------------------------------------------------------------------------------------------
# drape / fit (user surface)


class CLIError(ValueError):
    """A bad flag or file; the message names the problem and the fix (exit code 2)."""


DRAPE_EPILOG = """\
examples:
  physdrape drape                                   # bundled T-shirt, default body, relaxed pose -> ./physdrape_out/
  physdrape drape --category longsleeve --seed 3 --shape gender=0.2,weight=0.8 --pose stand --material denim
  physdrape drape --garment shirt.obj --garment tshirt:7 --out out/ --force --figures
  physdrape drape --bvh walk.bvh --frames 0:8 --out walk/
  physdrape drape --smpl-model SMPL_NEUTRAL.npz --garment smpl_shirt.obj --betas 1.2,-0.5 --amass seq.npz --frames 0:10
outputs (in --out): garment.obj/.ply, body.obj/.ply, drape.glb, render.png, report.json
  (several garments or frames: one numbered sub-directory each, one report.json);
  --figures adds residual.png (force heatmap, penetrating faces red), convergence.png
  (energy and force per solver step), materials.png (silk -> leather sweep of the first garment)
  and gallery.png (the four tiled).
sequences (--bvh / --amass with --frames A:B): warm-started by default: frame A is draped by the
  model from its own kinematic initialisation; each later frame starts from the previous frame's
  drape carried along by the body's motion (per garment vertex: blended skinning transform of
  frame t times the inverse of frame t-1's) and gets the solver steps and collision handler only
  (--warm-start model: the full model pass instead, which drifts over frames), one frame after
  the other. --no-warm-start drapes every frame from its own initialisation, all as one batch.
SMPL / SMPL-X (--smpl-model; model files are not shipped, https://smpl.is.tue.mpg.de): shape =
  --betas (up to 10 values, the rest 0), pose = --theta FILE.npy (axis-angles [rad], (24, 3) or
  (72,) for SMPL) or --amass FILE.npz (its betas are the shape unless --betas is given); the
  garment must be an .obj/.ply authored on SMPL's canonical body (beta = 0, zero pose).
"""


def _parse_shape(text: str | None) -> dict[str, float] | None:
    from physdrape.body.anny_body import PHENOTYPE_NAMES

    if text is None:
        return None
    values: dict[str, float] = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = item.partition("=")
        name = name.strip()
        if not sep:
            raise CLIError(f"--shape: {item!r} is not NAME=VALUE; e.g. --shape gender=0.3,weight=0.8 "
                           f"(names: {', '.join(PHENOTYPE_NAMES)})")
        if name not in PHENOTYPE_NAMES:
            raise CLIError(f"--shape: unknown phenotype {name!r}; valid names: {', '.join(PHENOTYPE_NAMES)}")
        try:
            v = float(value)
        except ValueError:
            raise CLIError(f"--shape: {name}={value!r} is not a number; phenotypes are values in [0, 1]") from None
        if not 0.0 <= v <= 1.0:
            raise CLIError(f"--shape: {name}={v:g} is outside [0, 1]; phenotypes are normalised values in [0, 1] "
                           "(0.5 = average)")
        values[name] = v
    return values


def _parse_frames(text: str) -> tuple[int, int]:
    a, sep, b = text.partition(":")
    try:
        start, stop = int(a), int(b)
    except ValueError:
        raise CLIError(f"--frames: {text!r} is not START:STOP (e.g. 0:8, stop excluded)") from None
    if not sep or start < 0 or stop <= start:
        raise CLIError(f"--frames: {text!r} must be START:STOP with 0 <= START < STOP")
    return start, stop


def _check_out_dir(out: Path, force: bool) -> None:
    """Refuse an existing non-empty output directory without --force, and unwritable places."""
    import os

    if out.exists() and not out.is_dir():
        raise CLIError(f"--out {out} exists and is not a directory; choose another path")
    if out.is_dir() and any(out.iterdir()) and not force:
        raise CLIError(f"--out {out} already holds files; pass --force to overwrite them or choose another --out")
    probe = out if out.exists() else out.parent
    while not probe.exists():
        probe = probe.parent
    if not os.access(probe, os.W_OK | os.X_OK):
        raise CLIError(f"--out {out}: {probe} is not writable; choose a directory you can write to")


def _material_from_args(args) -> object:
    from dataclasses import replace

    from physdrape.api import DrapeError, Draper
    from physdrape.physics.presets import out_of_range

    try:
        material = Draper.material(args.material)
    except DrapeError as exc:
        raise CLIError(f"--material: {exc}") from None
    overrides = {k: getattr(args, k) for k in ("mu", "lam", "k_bend", "density") if getattr(args, k) is not None}
    for k, v in overrides.items():
        if not v > 0:
            flag = "--" + k.replace("_", "-")
            raise CLIError(f"{flag} must be positive (SI units: --mu/--lam in Pa, --k-bend in J, "
                           f"--density in kg/m^2), got {v:g}")
    if overrides:
        material = replace(material, **overrides)
        for note in out_of_range(material):
            print(f"physdrape: warning: {note}; the model was trained only inside these ranges", file=sys.stderr)
    return material


def _garment_specs(args) -> list[str]:
    from physdrape.api import GARMENT_CATEGORIES

    specs = list(args.garment or [])
    for spec in specs:
        if spec == "default" or ":" in spec and spec.split(":")[0] in GARMENT_CATEGORIES:
            continue
        p = Path(spec).expanduser()
        if not p.is_file():
            raise CLIError(f"--garment {spec}: no such file (give an .obj/.ply in metres on the canonical body, "
                           f"a .mhclo, 'default', or CATEGORY:SEED with CATEGORY in {', '.join(GARMENT_CATEGORIES)})")
        if p.suffix.lower() not in (".obj", ".ply", ".mhclo"):
            raise CLIError(f"--garment {spec}: unsupported extension {p.suffix!r}; use .obj, .ply or .mhclo")
        try:
            with open(p, "rb") as handle:
                handle.read(1)
        except OSError as exc:
            raise CLIError(f"--garment {spec}: cannot read the file ({exc.strerror}); check its permissions") from None
    if args.category is not None or args.seed is not None:
        if args.category is None:
            raise CLIError(f"--seed needs --category (one of {', '.join(GARMENT_CATEGORIES)})")
        if args.category not in GARMENT_CATEGORIES:
            raise CLIError(f"--category: unknown category {args.category!r}; choose one of {', '.join(GARMENT_CATEGORIES)}")
        seed = 0 if args.seed is None else args.seed
        if seed < 0:
            raise CLIError(f"--seed must be >= 0, got {seed}")
        specs.append(f"{args.category}:{seed}")
    return specs or ["default"]


def _parse_betas(text: str | None) -> list[float] | None:
    import math

    if text is None:
        return None
    values = []
    for item in (p.strip() for p in text.split(",")):
        try:
            v = float(item)
        except ValueError:
            raise CLIError(f"--betas: {item!r} is not a number; give comma-separated SMPL shape coefficients, "
                           "e.g. --betas 1.2,-0.5,0.3") from None
        if not math.isfinite(v):
            raise CLIError(f"--betas: {item!r} is not finite; give numbers, e.g. --betas 1.2,-0.5")
        values.append(v)
    if not 1 <= len(values) <= 10:
        raise CLIError(f"--betas: {len(values)} values; give 1 to 10 SMPL shape coefficients (the rest are 0)")
    return values


def _smpl_pose_spec(args):
    """The pose of an SMPL drape: --theta FILE.npy, --amass FILE.npz (+ --frame/--frames) or rest."""
    import numpy as np


    if args.bvh is not None:
        raise CLIError("--bvh retargets onto Anny only; with --smpl-model give --amass FILE.npz (or --theta FILE.npy)")
    if args.pose is not None and args.pose not in ("rest", "t-pose"):
        raise CLIError(f"--pose {args.pose}: the presets are Anny poses; with --smpl-model give --theta FILE.npy "
                       "(axis-angles [rad]) or --amass FILE.npz")
    if args.theta is not None and args.amass is not None:
        raise CLIError("give either --theta or --amass, not both")
    if args.theta is not None:
        if args.frame is not None or args.frames is not None:
            raise CLIError("--frame/--frames select frames of an --amass file; --theta takes one pose array")
        path = Path(args.theta).expanduser()
        if not path.is_file():
            raise CLIError(f"--theta {args.theta}: no such file (a .npy of SMPL axis-angles [rad], shape (24, 3) "
                           "or (72,), or (N, 24, 3) for N poses)")
        try:
            theta = np.load(path, allow_pickle=False)
        except (ValueError, OSError) as exc:
            raise CLIError(f"--theta {args.theta}: cannot read it as a .npy array ({exc}); save θ with "
                           "numpy.save") from None
        return theta
    if args.amass is None:
        if args.frame is not None or args.frames is not None:
            raise CLIError("--frame/--frames select frames of an --amass file; give --amass FILE.npz")
        return None
    path = Path(args.amass).expanduser()
    if not path.is_file():
        raise CLIError(f"--amass {args.amass}: no such file")
    if path.suffix.lower() != ".npz":
        raise CLIError(f"--amass {args.amass}: expected an AMASS .npz (poses, betas)")
    return _motion(path, args)


def _motion(path: Path, args):
    from physdrape.api import Motion

    if args.frame is not None and args.frames is not None:
        raise CLIError("give either --frame N or --frames A:B, not both")
    if args.no_warm_start and args.warm_start not in (None, "off"):
        raise CLIError(f"give either --warm-start {args.warm_start} or --no-warm-start, not both")
    mode = "off" if args.no_warm_start else (args.warm_start or "solver")
    warm = False if mode == "off" else mode
    if args.frames is not None:
        return Motion(path, _parse_frames(args.frames), warm_start=warm)
    frame = 0 if args.frame is None else args.frame
    if frame < 0:
        raise CLIError(f"--frame must be >= 0, got {frame}")
    return Motion(path, frame, warm_start=warm)


def _pose_spec(args):
    from physdrape.body.poses import PRESETS

    if args.smpl_model is not None:
        return _smpl_pose_spec(args)
    if args.amass is not None or args.theta is not None:
        raise CLIError("--amass/--theta are SMPL poses; give --smpl-model FILE (the SMPL model .npz/.pkl) too")
    if args.bvh is None:
        if args.frame is not None or args.frames is not None:
            raise CLIError("--frame/--frames select frames of a --bvh file; give --bvh FILE")
        pose = args.pose
        if pose is not None and pose not in PRESETS:
            head, _, seed = pose.partition(":")
            if not (head == "random" and seed.isdigit()):
                raise CLIError(f"--pose: unknown pose {pose!r}; choose one of {', '.join(PRESETS)} or random:SEED "
                               "(or --bvh FILE)")
        return pose
    if args.pose is not None:
        raise CLIError("give either --pose or --bvh, not both")
    path = Path(args.bvh).expanduser()
    if not path.is_file():
        raise CLIError(f"--bvh {args.bvh}: no such file")
    if path.suffix.lower() != ".bvh":
        raise CLIError(f"--bvh {args.bvh}: expected a .bvh motion file (CMU skeleton)")
    return _motion(path, args)


def _safe(name: str) -> str:
    return "".join(c if c.isalnum() or c in "-_." else "_" for c in name)[:60]


def cmd_drape(args: argparse.Namespace) -> int:
    """Drape garments with the public API and write meshes, pictures and report.json."""
    import os
    import shutil
    import tempfile
    import time

    t_start = time.perf_counter()
    # 1. validate everything before any work or any write
    if args.steps is not None and args.steps < 0:
        raise CLIError(f"--steps must be >= 0, got {args.steps}")
    if args.batch_size < 1:
        raise CLIError(f"--batch-size must be >= 1, got {args.batch_size}")
    if not 32 <= args.render_size <= 4096:
        raise CLIError(f"--render-size must be in [32, 4096] pixels, got {args.render_size}")
    out = Path(args.out).expanduser()
    _check_out_dir(out, args.force)
    smpl = args.smpl_model is not None
    if smpl:
        if args.shape is not None:
            raise CLIError("--shape sets Anny phenotypes; an SMPL body is shaped by --betas b1,b2,...")
        if not Path(args.smpl_model).expanduser().exists():
            raise CLIError(f"--smpl-model {args.smpl_model}: no such file. SMPL/SMPL-X models are not shipped with "
                           "PhysDrape: download them from https://smpl.is.tue.mpg.de and pass the .npz/.pkl file "
                           "(or the folder holding SMPL_NEUTRAL.npz)")
        if not args.garment or args.category is not None or args.seed is not None:
            raise CLIError("with --smpl-model give --garment FILE (.obj/.ply, metres, y-up) authored on SMPL's "
                           "canonical body (beta = 0, zero pose): the bundled default and --category garments are "
                           "made for the Anny body and do not fit SMPL")
        shape = _parse_betas(args.betas)
    else:
        if args.betas is not None:
            raise CLIError("--betas shapes an SMPL body; give --smpl-model FILE too (Anny bodies take --shape)")
        shape = _parse_shape(args.shape)
    pose = _pose_spec(args)
    material = _material_from_args(args)
    garments = _garment_specs(args)
    if args.checkpoint is not None and not Path(args.checkpoint).expanduser().exists():
        raise CLIError(f"--checkpoint {args.checkpoint}: no such directory (a checkpoint directory with "
                       "model.safetensors + config.json, or a training run directory)")
    if args.threads:
        torch.set_num_threads(args.threads)

    # 2. drape (the API validates meshes, phenotypes and the checkpoint)
    from physdrape import api
    from physdrape.export import save_result, write_json
    from physdrape.render import (
        compose_gallery,
        convergence_figure,
        material_sweep_figure,
        render_result,
    )

    try:
        draper = api.Draper(args.checkpoint, steps=15 if args.steps is None else args.steps,
                            smpl_model=args.smpl_model, smpl_gender=args.smpl_gender)
        results = draper.drape(garments, shape=shape, pose=pose, material=material, refine=args.refine,
                               keep_trace=args.figures, batch_size=args.batch_size, progress=len(garments) > 1 or
                               isinstance(pose, api.Motion) and not isinstance(pose.frames, int))
        sweep = None
        if args.figures:
            from physdrape.physics.presets import MATERIAL_PRESETS

            if isinstance(pose, api.Motion):
                first_pose = api.Motion(pose.path, pose.frames if isinstance(pose.frames, int) else pose.frames[0])
            elif pose is not None and not isinstance(pose, str):  # SMPL θ array: its first pose
                first_pose = draper.poses(pose)[0].pose[0].numpy()
            else:
                first_pose = pose
            sweep = draper.drape(garments[0], shape=shape, pose=first_pose, material=list(MATERIAL_PRESETS.values()))
    except api.DrapeError as exc:
        raise CLIError(str(exc)) from None

    # 3. write everything into a temporary directory beside --out, then move the files in
    parent = out.parent if out.parent.exists() else None
    if parent is None:
        out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out.name}.", dir=out.parent))
    try:
        reports = []
        for k, res in enumerate(results):
            sub = tmp if len(results) == 1 else tmp / f"{k:03d}_{_safe(res.name)}_{_safe(res.pose)}"
            save_result(res, sub)
            render_result(res, sub / "render.png", size=args.render_size)
            if args.figures:
                render_result(res, sub / "residual.png", mode="residual", size=args.render_size)
                convergence_figure(res, sub / "convergence.png")
            entry = res.report()
            entry["directory"] = "." if sub == tmp else sub.name
            reports.append(entry)
        if sweep is not None:
            from physdrape.physics.presets import MATERIAL_PRESETS

            material_sweep_figure(sweep, list(MATERIAL_PRESETS), tmp / "materials.png", size=args.render_size)
            first = tmp if len(results) == 1 else tmp / reports[0]["directory"]
            compose_gallery([first / "render.png", first / "residual.png", first / "convergence.png",
                             tmp / "materials.png"], tmp / "gallery.png", columns=2)
        wall = time.perf_counter() - t_start
        report = {
            "physdrape_version": _version(),
            "checkpoint": str(draper.checkpoint),
            "steps": draper.steps,
            "refine": bool(args.refine),
            "shape": (shape or {}) if not smpl else {"betas": shape or "from the AMASS file or 0"},
            "body": "smpl" if smpl else "anny",
            "num_results": len(results),
            "wall_time_s": wall,
            "results": reports,
        }
        write_json(tmp / "report.json", report)
        out.mkdir(parents=True, exist_ok=True)
        for path in sorted(tmp.rglob("*")):
            if path.is_file():
                dest = out / path.relative_to(tmp)
                dest.parent.mkdir(parents=True, exist_ok=True)
                os.replace(path, dest)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for r in reports:
        print(f"{r['garment']} [{r['pose']}]: E_strain {r['E_strain_J']:.4g} J, E_bend {r['E_bend_J']:.4g} J, "
              f"B2G {r['B2G_percent']:.3g} %, residual {r['residual_force_N']:.3g} N")
    print(f"wrote {len(results)} drape(s) to {out} in {report['wall_time_s']:.2f} s")
    return 0


def _version() -> str:
    from physdrape import __version__

    return __version__


def cmd_fit(args: argparse.Namespace) -> int:
    """Place a garment authored for another body onto the canonical body, relax it, validate, write."""
    import time

    out = Path(args.out).expanduser()
    if out.suffix.lower() not in (".obj", ".ply"):
        raise CLIError(f"--out {args.out}: the fitted garment is written as .obj or .ply; give such a file name")
    if out.exists() and not args.force:
        raise CLIError(f"--out {out} exists; pass --force to overwrite it")
    if out.exists() and out.is_dir():
        raise CLIError(f"--out {out} is a directory; give a file name ending in .obj or .ply")
    _check_out_dir(out.parent, True)
    src = Path(args.garment).expanduser()
    if not src.is_file():
        raise CLIError(f"{args.garment}: no such file (an .obj/.ply in metres, or a MakeHuman .mhclo)")
    if src.suffix.lower() not in (".obj", ".ply", ".mhclo"):
        raise CLIError(f"{args.garment}: unsupported extension {src.suffix!r}; use .obj, .ply or .mhclo")
    if args.iters < 0:
        raise CLIError(f"--iters must be >= 0, got {args.iters}")
    from physdrape.api import DrapeError, fit_garment
    from physdrape.geometry.mesh import write_mesh

    t0 = time.perf_counter()
    try:
        result = fit_garment(src, align=not args.no_align, scale=args.scale, iters=args.iters,
                             time_budget_s=args.time_budget)
    except DrapeError as exc:
        raise CLIError(str(exc)) from None
    report = result.report()
    report["wall_time_s"] = time.perf_counter() - t0
    print(json.dumps(report, indent=2))
    if not result.ok:
        if not args.keep_invalid:
            raise CLIError(f"the fitted garment failed validation (nothing written; --keep-invalid writes it "
                           f"anyway):\n{result.validation}")
        print("physdrape: warning: writing a garment that failed validation (--keep-invalid)", file=sys.stderr)
    write_mesh(out, result.verts, result.faces)  # atomic
    print(f"wrote {out}")
    return 0


def add_drape_parsers(sub) -> None:
    """The `drape` and `fit` subcommands."""
    from physdrape.body.poses import PRESETS
    from physdrape.physics.presets import MATERIAL_PRESETS

    drape = sub.add_parser("drape", help="drape garments on a shaped, posed body (no arguments: the bundled "
                           "T-shirt on the default body)", epilog=DRAPE_EPILOG,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    g = drape.add_argument_group("garments")
    g.add_argument("--garment", action="append", metavar="FILE|default|CATEGORY:SEED",
                   help="garment on the canonical body: .obj/.ply (metres, y-up) or .mhclo; repeat for a batch")
    g.add_argument("--category", help="generate a garment: tshirt, longsleeve, tanktop or croptop")
    g.add_argument("--seed", type=int, help="seed of the generated garment (with --category; default 0)")
    b = drape.add_argument_group("body")
    b.add_argument("--shape", metavar="NAME=V,...", help="Anny phenotypes in [0, 1] (gender, age, muscle, weight, "
                   "height, proportions; missing ones 0.5), e.g. gender=0.2,weight=0.8")
    b.add_argument("--pose", metavar="NAME|random:SEED", help=f"pose preset ({', '.join(PRESETS)}; default relaxed) "
                   "or random:SEED (anatomical sampler)")
    b.add_argument("--bvh", metavar="FILE", help="CMU BVH motion file; retargeted onto Anny")
    b.add_argument("--frame", type=int, help="frame of --bvh / --amass (default 0)")
    b.add_argument("--frames", metavar="A:B", help="frames A..B-1 of --bvh / --amass, warm-started frame by frame "
                   "(see below)")
    b.add_argument("--warm-start", choices=("solver", "model", "off"), help="how later --frames start from the "
                   "previous frame's drape: solver (default: solver steps + collision handler only), model (full "
                   "model pass; drifts), off (= --no-warm-start)")
    b.add_argument("--no-warm-start", action="store_true", help="drape --frames independently, as one batch, each "
                   "from its own kinematic initialisation")
    s = drape.add_argument_group("SMPL / SMPL-X body (bring your own model file)")
    s.add_argument("--smpl-model", metavar="FILE", help="SMPL/SMPL+H/SMPL-X model .npz (or legacy .pkl), or a folder "
                   "holding SMPL_NEUTRAL.npz; drapes on that body instead of Anny")
    s.add_argument("--smpl-gender", default="neutral", help="picks SMPL_{GENDER} in a --smpl-model folder "
                   "(default neutral)")
    s.add_argument("--betas", metavar="B1,B2,...", help="SMPL shape coefficients (up to 10; missing ones 0)")
    s.add_argument("--theta", metavar="FILE.npy", help="SMPL pose: axis-angles [rad], (24, 3) or (72,) for SMPL, "
                   "(N, 24, 3) for N poses")
    s.add_argument("--amass", metavar="FILE.npz", help="AMASS sequence (poses, betas); pick frames with --frame / "
                   "--frames")
    m = drape.add_argument_group("material (SI units)")
    m.add_argument("--material", help=f"fabric preset: {', '.join(MATERIAL_PRESETS)} (default cotton)")
    m.add_argument("--mu", type=float, help="Lame shear modulus [Pa] (trained 1.59e4..6.36e4)")
    m.add_argument("--lam", type=float, help="Lame first parameter [Pa] (trained 3.5e3..9.33e4)")
    m.add_argument("--k-bend", type=float, dest="k_bend", help="bending stiffness [J] (trained 6.4e-8..1.3e-3)")
    m.add_argument("--density", type=float, help="area density [kg/m^2] (trained 0.043..0.7)")
    r = drape.add_argument_group("model and output")
    r.add_argument("--checkpoint", help="checkpoint or run directory (default: the bundled model)")
    r.add_argument("--steps", type=int, help="explicit solver steps T (default 15)")
    r.add_argument("--refine", action="store_true", help="polish with the physics oracle (projected Newton, slow)")
    r.add_argument("--batch-size", type=int, default=8, help="garments per model call (default 8)")
    r.add_argument("--out", default="physdrape_out", help="output directory (default ./physdrape_out)")
    r.add_argument("--force", action="store_true", help="overwrite files in a non-empty --out")
    r.add_argument("--figures", action="store_true", help="also write residual.png, convergence.png, materials.png, "
                   "gallery.png")
    r.add_argument("--render-size", type=int, default=640, help="height of the pictures [px] (default 640)")
    r.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    drape.set_defaults(func=cmd_drape)

    fit = sub.add_parser("fit", help="place a garment authored for another body onto the canonical body")
    fit.add_argument("garment", help="an .obj/.ply in metres (y-up) or a MakeHuman .mhclo")
    fit.add_argument("--out", required=True, help="the fitted template (.obj or .ply)")
    fit.add_argument("--force", action="store_true", help="overwrite --out")
    fit.add_argument("--iters", type=int, default=20, help="physics relaxation iterations (0: align only)")
    fit.add_argument("--time-budget", type=float, default=120.0, help="relaxation wall-time budget [s]")
    fit.add_argument("--scale", type=float, default=1.0, help="uniform scale applied first (e.g. 0.95 for a garment "
                     "made for a taller body; default 1)")
    fit.add_argument("--no-align", action="store_true", help="skip the translation search")
    fit.add_argument("--keep-invalid", action="store_true", help="write the result even if validation fails")
    fit.set_defaults(func=cmd_fit)


def cmd_train(args: argparse.Namespace) -> int:
    """Train a model (data-parallel under torchrun: gloo on CPU, NCCL on GPUs)."""
    import os

    import torch.distributed as dist

    from physdrape.config_io import load_config
    from physdrape.train.data import DrapeSource
    from physdrape.train.trainer import TrainConfig, Trainer

    config = load_config(TrainConfig, args.config)
    if args.steps is not None:
        from dataclasses import replace

        config = replace(config, optim=replace(config.optim, steps=args.steps))
    distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if distributed:
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    if args.threads:
        torch.set_num_threads(args.threads)
    try:
        trainer = Trainer(config, DrapeSource(config.data), args.run_dir)
        trainer.run(resume=args.resume)
    finally:
        if distributed:
            dist.barrier()  # no rank tears gloo down while another still talks to it
            dist.destroy_process_group()
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="physdrape", description="Drape garments onto bodies with PhysDrape.")
    sub = parser.add_subparsers(dest="command", required=True)
    add_drape_parsers(sub)
    train = sub.add_parser("train", help="train a PhysDrape model (self-supervised, resumable)")
    train.add_argument("--config", required=True, help="YAML run config (see configs/cpu_default.yaml)")
    train.add_argument("--run-dir", required=True, help="directory for checkpoints, metrics.jsonl, TensorBoard")
    train.add_argument("--resume", action="store_true", help="continue from the run directory's latest checkpoint")
    train.add_argument("--steps", type=int, help="override optim.steps")
    train.add_argument("--threads", type=int, default=0, help="torch threads per process (0: torch's default)")
    train.set_defaults(func=cmd_train)
    _add_eval(sub)
    return parser


def _add_eval(sub) -> None:
    """The `eval` subcommand lives in `physdrape.eval.cli` (added when that module exists)."""
    try:
        from physdrape.eval.cli import add_parser
    except ModuleNotFoundError as exc:
        if exc.name != "physdrape.eval.cli":
            raise  # a broken dependency of eval must not hide the subcommand silently
        return
    add_parser(sub)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (CLIError, MeshError, ConfigError, CheckpointError, DrapeError) as exc:
        print(f"physdrape: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())

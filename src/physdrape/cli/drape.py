"""`physdrape drape`: parse the flags into the API's arguments, drape with the public API
(`physdrape.api.Draper`), and write meshes, pictures and report.json atomically into --out.
With --manifest, `physdrape.cli.drape_manifest` drapes a file of jobs instead.

The API validates garments, bodies, poses, materials and the checkpoint; this module checks only
what belongs to the command line (flag syntax, flag combinations, the output folder)."""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from physdrape import __version__
from physdrape.api import GARMENT_CATEGORIES, Draper, DrapeWarning, Motion
from physdrape.api.placement import UNITS
from physdrape.cli import drape_manifest
from physdrape.cli.common import (
    CLIError,
    add_device_argument,
    check_out_dir,
    commit_directory,
    process_device,
    safe_name,
    staged_directory,
)
from physdrape.physics.grip import DEFAULT_GRIP_STIFFNESS
from physdrape.progress import slow_phase

DRAPE_EPILOG = """\
examples:
  physdrape drape                                   # bundled T-shirt, default body, relaxed pose -> ./physdrape_out/
  physdrape drape --category longsleeve --seed 3 --shape gender=0.2,weight=0.8 --pose stand --material denim
  physdrape drape --garment shirt.obj --garment tshirt:7 --out out/ --force --figures
  physdrape drape --bvh walk.bvh --frames 0:8 --out walk/
  physdrape drape --smpl-model SMPL_NEUTRAL.npz --garment smpl_shirt.obj --betas 1.2,-0.5 --amass seq.npz --frames 0:10
  physdrape drape --manifest jobs.jsonl --out dataset/          # one job per line -> dataset/<id>/ (docs/manifest.md)
  torchrun --nnodes 1 --nproc-per-node 4 -m physdrape.cli drape --manifest jobs.jsonl --out dataset/
outputs (in --out, metres whatever --units): garment.obj/.ply, body.obj/.ply, drape.glb, render.png,
  report.json (docs/report.md: every field) (several garments or frames: one numbered sub-directory
  each, one report.json). --force replaces an existing --out as a whole, once the new run is
  complete; Ctrl-C leaves --out as it was.
  --figures adds residual.png (force heatmap, penetrating faces red), convergence.png
  (energy and force per solver step), materials.png (silk -> leather sweep of the first garment)
  and gallery.png (the four tiled; for a batch also every garment's render).
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
manifests (--manifest JOBS.jsonl; docs/manifest.md): one job per line, e.g. {"id": "a1", "garment":
  "tshirt:7", "shape": {"weight": 0.8}, "pose": "stand", "material": "denim"}; each job is written
  whole into --out/<id>/ (--outputs lean: garment.ply + report.json); a rerun skips finished jobs;
  under torchrun job j is draped by rank j mod WORLD_SIZE; each rank writes summary.rankR-of-W.json.
"""


def _parse_shape(text: str | None) -> dict[str, float] | None:
    """--shape NAME=V,... as a dict (names and ranges are checked by the API)."""
    if text is None:
        return None
    values: dict[str, float] = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        name, sep, value = item.partition("=")
        if not sep:
            raise CLIError(f"--shape: {item!r} is not NAME=VALUE; e.g. --shape gender=0.3,weight=0.8")
        try:
            values[name.strip()] = float(value)
        except ValueError:
            raise CLIError(f"--shape: {name}={value!r} is not a number; phenotypes are values in [0, 1]") from None
    return values


def _parse_betas(text: str | None) -> list[float] | None:
    """--betas b1,b2,... as a list of numbers (their count and size are checked by the API)."""
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


def _motion(path: str, args) -> Motion:
    if args.frame is not None and args.frames is not None:
        raise CLIError("give either --frame N or --frames A:B, not both")
    if args.no_warm_start and args.warm_start not in (None, "off"):
        raise CLIError(f"give either --warm-start {args.warm_start} or --no-warm-start, not both")
    mode = "off" if args.no_warm_start else (args.warm_start or "solver")
    warm = False if mode == "off" else mode
    if args.frames is not None:
        return Motion(path, _parse_frames(args.frames), warm_start=warm, clear_arms=not args.keep_arms)
    frame = 0 if args.frame is None else args.frame
    if frame < 0:
        raise CLIError(f"--frame must be >= 0, got {frame}")
    return Motion(path, frame, warm_start=warm, clear_arms=not args.keep_arms)


def _theta(path_text: str) -> np.ndarray:
    """--theta FILE.npy: the SMPL pose array (its shape is checked by the API)."""
    path = Path(path_text).expanduser()
    if not path.is_file():
        raise CLIError(f"--theta {path_text}: no such file (a .npy of SMPL axis-angles [rad], shape (24, 3) "
                       "or (72,), or (N, 24, 3) for N poses)")
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise CLIError(f"--theta {path_text}: cannot read it as a .npy array ({exc}); save θ with "
                       "numpy.save") from None


def _pose_spec(args):
    """The API's pose argument from --pose, --bvh, --amass or --theta (with --frame / --frames)."""
    smpl = args.smpl_model is not None
    if smpl and args.bvh is not None:
        raise CLIError("--bvh retargets onto Anny only; with --smpl-model give --amass FILE.npz (or --theta FILE.npy)")
    if smpl and args.pose is not None and args.pose not in ("rest", "t-pose"):
        raise CLIError(f"--pose {args.pose}: the presets are Anny poses; with --smpl-model give --theta FILE.npy "
                       "(axis-angles [rad]) or --amass FILE.npz")
    if not smpl and (args.amass is not None or args.theta is not None):
        raise CLIError("--amass/--theta are SMPL poses; give --smpl-model FILE (the SMPL model .npz/.pkl) too")
    if args.theta is not None and args.amass is not None:
        raise CLIError("give either --theta or --amass, not both")
    if args.pose is not None and args.bvh is not None:
        raise CLIError("give either --pose or --bvh, not both")
    motion = args.bvh if args.bvh is not None else args.amass
    if motion is None and (args.frame is not None or args.frames is not None):
        raise CLIError("--frame/--frames select frames of a --bvh file (or an --amass file); give "
                       + ("--amass FILE.npz" if smpl else "--bvh FILE"))
    if args.theta is not None:
        return _theta(args.theta)
    if motion is not None:
        return _motion(motion, args)
    return args.pose


def _material(args, notes: list[str]):
    """The API's material: the --material preset with any --mu/--lam/--k-bend/--density override
    (values outside the trained ranges are warned about and added to `notes`)."""
    from physdrape.physics.presets import out_of_range

    material = Draper.material(args.material)
    overrides = {k: getattr(args, k) for k in ("mu", "lam", "k_bend", "density") if getattr(args, k) is not None}
    for k, v in overrides.items():
        if not v > 0:
            raise CLIError(f"--{k.replace('_', '-')} must be positive (SI units: --mu/--lam in Pa, --k-bend in J, "
                           f"--density in kg/m^2), got {v:g}")
    if overrides:
        material = replace(material, **overrides)
        for note in out_of_range(material):
            notes.append(f"{note}; the model was trained only inside these ranges")
            print(f"physdrape: warning: {notes[-1]}", file=sys.stderr)
    return material


def _garment_specs(args) -> list[str]:
    """The API's garment specs: every --garment, plus CATEGORY:SEED from --category / --seed."""
    specs = list(args.garment or [])
    if args.category is not None or args.seed is not None:
        if args.category is None:
            raise CLIError(f"--seed needs --category (one of {', '.join(GARMENT_CATEGORIES)})")
        if args.category not in GARMENT_CATEGORIES:
            raise CLIError(f"--category: unknown category {args.category!r}; choose one of "
                           f"{', '.join(GARMENT_CATEGORIES)}")
        if args.seed is not None and args.seed < 0:
            raise CLIError(f"--seed must be >= 0, got {args.seed}")
        specs.append(f"{args.category}:{args.seed or 0}")
    if args.smpl_model is not None and (not args.garment or args.category is not None):
        raise CLIError("with --smpl-model give --garment FILE (.obj/.ply, metres, y-up) authored on SMPL's "
                       "canonical body (beta = 0, zero pose): the bundled default and --category garments are "
                       "made for the Anny body and do not fit SMPL")
    return specs or ["default"]


def _shape(args):
    """The API's shape: Anny phenotypes from --shape, or SMPL β from --betas."""
    if args.smpl_model is not None:
        if args.shape is not None:
            raise CLIError("--shape sets Anny phenotypes; an SMPL body is shaped by --betas b1,b2,...")
        return _parse_betas(args.betas)
    if args.betas is not None:
        raise CLIError("--betas shapes an SMPL body; give --smpl-model FILE too (Anny bodies take --shape)")
    return _parse_shape(args.shape)


def _output_dir(args) -> Path:
    """--out as a path (a symbolic link to a folder: that folder, which is replaced in place)."""
    out = Path(args.out).expanduser()
    return out.resolve() if out.is_symlink() else out


def _interrupted(args, argv) -> str:
    out = _output_dir(args)
    return f"nothing was written to {out}" + ("; its earlier contents are unchanged" if out.exists() else "")


def _drape_noting_warnings(notes: list[str], fn, *a, **kw):
    """`fn(*a, **kw)`, its `DrapeWarning`s printed as `physdrape: warning:` lines and added to `notes`."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", DrapeWarning)
        result = fn(*a, **kw)
    for w in caught:
        if not issubclass(w.category, DrapeWarning):
            warnings.showwarning(w.message, w.category, w.filename, w.lineno)
        elif str(w.message) not in notes:
            notes.append(str(w.message))
            print(f"physdrape: warning: {w.message}", file=sys.stderr)
    return result


def cmd_drape(args: argparse.Namespace) -> int:
    """Drape garments with the public API and write meshes, pictures and report.json."""
    from physdrape.export import save_result, write_json
    from physdrape.physics.presets import MATERIAL_PRESETS
    from physdrape.render import compose_gallery, convergence_figure, material_sweep_figure, render_result

    if args.manifest is not None:
        return drape_manifest.cmd_manifest(args)
    t_start = time.perf_counter()
    # 1. the command line's own checks, before any work or any write
    if not 32 <= args.render_size <= 4096:
        raise CLIError(f"--render-size must be in [32, 4096] pixels, got {args.render_size}")
    out = _output_dir(args)
    check_out_dir(out, args.force, replaces="report.json")
    smpl = args.smpl_model is not None
    shape, pose, garments = _shape(args), _pose_spec(args), _garment_specs(args)
    notes: list[str] = []
    material = _material(args, notes)
    if args.threads:
        torch.set_num_threads(args.threads)

    # 2. drape (the API validates garments, units, placement, bodies, poses and the checkpoint)
    draper = Draper(args.checkpoint, steps=15 if args.steps is None else args.steps, smpl_model=args.smpl_model,
                    smpl_gender=args.smpl_gender, device=process_device(args.device),
                    follow_planes=args.follow_planes, passes=args.passes, compile_network=args.compile)
    common = {"shape": shape, "units": args.units, "allow_detached": args.allow_detached, "sizing": args.sizing,
              "grip": args.grip, "closures": args.closures, "layers": args.layers}
    what = "draping" + (" and polishing with the physics oracle (--refine)" if args.refine else "")
    with slow_phase(what):
        results = _drape_noting_warnings(
            notes, draper.drape, garments, pose=pose, material=material, refine=args.refine, keep_trace=args.figures,
            batch_size=args.batch_size,
            progress=len(garments) > 1 or isinstance(pose, Motion) and not isinstance(pose.frames, int), **common)
    sweep = None
    if args.figures:
        if isinstance(pose, Motion):
            first_pose = Motion(pose.path, pose.frames if isinstance(pose.frames, int) else pose.frames[0],
                                clear_arms=pose.clear_arms)
        elif pose is not None and not isinstance(pose, str):  # SMPL θ array: its first pose
            first_pose = draper.poses(pose)[0].pose[0].numpy()
        else:
            first_pose = pose
        with slow_phase("draping the material sweep for --figures"):
            sweep = _drape_noting_warnings(notes, draper.drape, garments[0], pose=first_pose,
                                           material=list(MATERIAL_PRESETS.values()), **common)

    # 3. write everything into a temporary folder beside --out, then put it in place as a whole
    with staged_directory(out) as tmp, slow_phase(f"writing meshes and pictures into {out}"):
        reports = []
        for k, res in enumerate(results):
            sub = tmp if len(results) == 1 else tmp / f"{k:03d}_{safe_name(res.name)}_{safe_name(res.pose)}"
            save_result(res, sub)
            render_result(res, sub / "render.png", size=args.render_size)
            if args.figures:
                render_result(res, sub / "residual.png", mode="residual", size=args.render_size)
                convergence_figure(res, sub / "convergence.png")
            entry = res.report()
            entry["directory"] = "." if sub == tmp else sub.name
            reports.append(entry)
        if sweep is not None:
            material_sweep_figure(sweep, list(MATERIAL_PRESETS), tmp / "materials.png", size=args.render_size)
            first = tmp if len(results) == 1 else tmp / reports[0]["directory"]
            batch = [] if len(results) == 1 else [tmp / r["directory"] / "render.png" for r in reports]
            compose_gallery([first / "render.png", first / "residual.png", first / "convergence.png",
                             tmp / "materials.png"], tmp / "gallery.png", columns=3,
                            heading=None if not batch else f"first garment: {results[0].name} [{results[0].pose}]",
                            batch=batch, batch_captions=[f"{r.name} [{r.pose}]" for r in results] if batch else ())
        wall = time.perf_counter() - t_start
        report = {
            "physdrape_version": __version__,
            "checkpoint": str(draper.checkpoint),
            "passes": draper.model_config.passes,
            "steps": draper.steps,
            "refine": bool(args.refine),
            "shape": (shape or {}) if not smpl else {"betas": shape or "from the AMASS file or 0"},
            "body": "smpl" if smpl else "anny",
            "units": args.units,
            "warnings": notes,
            "num_results": len(results),
            "wall_time_s": wall,
            "results": reports,
        }
        write_json(tmp / "report.json", report)
        commit_directory(tmp, out, force=args.force, replaces="report.json")
    for r in reports:
        print(f"{r['garment']} [{r['pose']}]: E_strain {r['E_strain_J']:.4g} J, E_bend {r['E_bend_J']:.4g} J, "
              f"B2G {r['B2G_percent']:.3g} %, residual {r['residual_force_N']:.3g} N")
    print(f"wrote {len(results)} drape(s) to {out} in {report['wall_time_s']:.2f} s")
    return 0


def add_parser(sub) -> None:
    """The `drape` subcommand."""
    from physdrape.body.poses import PRESETS
    from physdrape.physics.presets import MATERIAL_PRESETS

    drape = sub.add_parser("drape", help="drape garments on a shaped, posed body (no arguments: the bundled "
                           "T-shirt on the default body)", epilog=DRAPE_EPILOG,
                           formatter_class=argparse.RawDescriptionHelpFormatter)
    g = drape.add_argument_group("garments")
    g.add_argument("--garment", action="append", metavar="FILE|default|CATEGORY:SEED",
                   help="garment on the canonical body: .obj/.ply (metres, y-up) or .mhclo; repeat for a batch")
    g.add_argument("--category", help="generate a garment: a top (tshirt, longsleeve, tanktop, croptop), shorts, "
                   "capri or trousers, or an outfit (a top over trousers)")
    g.add_argument("--seed", type=int, help="seed of the generated garment (with --category; default 0)")
    g.add_argument("--units", choices=tuple(UNITS), default="m", help="unit of --garment .obj/.ply files "
                   "(default m); they are converted to metres, and so are the outputs")
    g.add_argument("--allow-detached", action="store_true", help="drape a garment that neither touches nor "
                   "surrounds the canonical body (a warning instead of an error)")
    g.add_argument("--sizing", choices=("fit", "fixed"), default=None, help="the garment's rest shape on the body: "
                   "fit = follows the body's shape (worn where it was authored), fixed = the template's (one size "
                   "tried on); default fit for .mhclo, fixed for other garments")
    g.add_argument("--grip", type=float, default=None, metavar="K", help="grip stiffness [N/m^3] of the "
                   "waistband of trousers or a skirt (alone or under a top), held where it was put on as friction "
                   f"holds it (0: off; default {DEFAULT_GRIP_STIFFNESS:g})")
    g.add_argument("--closures", choices=("auto", "off"), default="auto", help="tie a garment's overlapping panels "
                   "(button and wrap fronts, layered collars) with stitches where they overlap on the canonical body "
                   "(default auto)")
    g.add_argument("--layers", choices=("auto", "off"), default="auto", help="keep a multi-piece garment's pieces "
                   "in the order they overlap on the canonical body, the outer outside the inner (default auto)")
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
    b.add_argument("--keep-arms", action="store_true", help="drape --bvh/--amass frames as recorded; by default an "
                   "arm hanging against the torso is turned out at the shoulder until it stands 2 cm off it "
                   "(the cloth caught between them has no way out in a static drape; report.json says by how "
                   "many degrees)")
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
    r.add_argument("--follow-planes", action=argparse.BooleanOptionalAction, dest="follow_planes",
                   help="follow the body at every solver step where the garment is near it, or hold its planes "
                        "between body queries (default: the checkpoint's; the bundled model follows them)")
    r.add_argument("--passes", type=int, help="network passes before the solver, each looking again at the garment "
                                              "the passes before it moved (default: the checkpoint's)")
    r.add_argument("--compile", action="store_true", help="run the network compiled by torch.compile: the first "
                   "drape compiles it (seconds to tens of seconds), later ones run it faster; for many garments, poses "
                   "or a --manifest")
    r.add_argument("--refine", action="store_true", help="polish with the physics oracle (projected Newton, slow)")
    r.add_argument("--batch-size", type=int, default=8, help="garments per model call (default 8)")
    r.add_argument("--out", default="physdrape_out", help="output directory (default ./physdrape_out)")
    r.add_argument("--force", action="store_true", help="replace an earlier run's --out (it holds report.json) "
                   "as a whole, once the new run is complete")
    r.add_argument("--figures", action="store_true", help="also write residual.png, convergence.png, materials.png, "
                   "gallery.png")
    r.add_argument("--render-size", type=int, default=640, help="height of each body view in the pictures [px] (default 640)")
    r.add_argument("--threads", type=int, default=0, help="torch threads (0: torch's default)")
    add_device_argument(r)
    drape_manifest.add_arguments(drape)
    drape.set_defaults(func=cmd_drape, interrupted=_interrupted)

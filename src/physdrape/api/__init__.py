"""The public Python API: drape garments onto Anny bodies with a trained PhysDrape model.

Example (the README snippet; `tests/api/test_api.py` runs it with a test model)::

    import physdrape

    draper = physdrape.Draper()  # loads the bundled model once; Draper(device="cuda") runs it on a GPU
    # garments: "default" (bundled T-shirt), "tshirt:7" / "trousers:2" / "outfit:5" (generated), "shirt.obj", "suit.mhclo", (verts, faces)
    [res] = draper.drape("default", shape={"weight": 0.8, "gender": 0.3}, pose="stand", material="denim")
    print(res.verts.shape, res.metrics["b2g_percent"], res.timings["total_s"])
    res.save("out/")  # garment.obj/.ply, body.obj/.ply, drape.glb
    res.render("out/render.png")

Conventions: SI units, y-up metres; garment templates sit on the canonical Anny body (all
phenotypes 0.5, rest A-pose), around or on it (a garment that neither touches nor surrounds it is
refused unless ``allow_detached=True``). Garment files and meshes in another unit are read with
``units="cm"`` (or "dm", "mm"); results are in metres. One model pass plus `steps` explicit
solver steps per batch.

SMPL / SMPL-X (model files never shipped): ``Draper(smpl_model="SMPL_NEUTRAL.npz")`` (or
``body=SMPLBody(...)``) drapes on that body instead: shape = β, pose = θ or AMASS frames
(``Motion("seq.npz", frames=(0, 10))``); garments must then be files authored on SMPL's canonical
body (β = 0, rest T-pose), since the bundled and generated garments are made for Anny.

Sequences: a multi-frame `Motion` is draped frame by frame with a warm start (each frame starts
from the previous frame's drape carried along by the body's motion, see `Motion`);
``Motion(..., warm_start=False)`` drapes every frame independently, as one batch.

Devices: ``Draper(device="cuda")`` poses the bodies, skins the garments and runs the model, its
solver and collision handler and the body queries on a GPU (the default is "cpu"); a motion's
warm starts and the oracle's refinement run on the CPU, and results are numpy arrays either way.

Datasets: `run_manifest(draper, "jobs.jsonl", "out/")` drapes a JSON-lines manifest, one job per
line, into one folder per job, resumable and sharded by rank (docs/manifest.md).

Modules: `types` (the error and result types), `specs` (garment, shape, pose and material specs),
`sequences` (warm-started motions), `placement` (the garment's unit and its place on the body),
`draper` (the `Draper`), `fitting` (`fit_garment`), `manifest` (reading a manifest of jobs) and
`manifest_run` (draping one, sharded and resumable).
"""

from physdrape.api.draper import Draper, drape
from physdrape.api.fitting import fit_garment
from physdrape.api.manifest import Manifest, ManifestError, ManifestJob, read_manifest
from physdrape.api.manifest_run import ManifestSummary, Outputs, ranks_from_env, run_manifest
from physdrape.api.specs import DEFAULT_POSE, GARMENT_CATEGORIES, load_smpl_body
from physdrape.api.types import DrapeError, DrapeResult, DrapeWarning, FitResult, Motion

__all__ = ["DEFAULT_POSE", "GARMENT_CATEGORIES", "DrapeError", "DrapeResult", "DrapeWarning", "Draper", "FitResult",
           "Manifest", "ManifestError", "ManifestJob", "ManifestSummary", "Motion", "Outputs", "drape", "fit_garment",
           "load_smpl_body", "ranks_from_env", "read_manifest", "run_manifest"]

"""A classical cloth simulator as a baseline: Newton's VBD (vertex block descent) solver on CPU vs. PhysDrape.

Same instances as `bench/bench_speed.py` (the evaluation protocol's `_test_instances`, default
material, one garment per instance). Per instance:

- PhysDrape (T = 15, `load_model` + `run_model`; median of `--repeats` timed calls after a
  warm-up): wall time and OUR total energy (E_strain + E_bend + E_grav + contact penalty,
  `physdrape.eval.evaluate.total_energy`).
- Newton VBD (`newton.solvers.SolverVBD`, `device="cpu"`): a damped dynamic simulation from X_init
  with the garment template as rest shape and the posed body as a static triangle-mesh collider,
  until it settles (max vertex speed < `--settle-speed` at a check, or OUR energy varied by less
  than `--settle-rel` of itself over the last `--settle-window` simulated seconds) or `--budget`
  seconds of wall time are spent. Every `--check-every` simulated seconds OUR total energy is
  evaluated on the current positions (the clock is paused meanwhile: the history's wall times are pure VBD time);
  reported: the VBD wall time at which that energy first is <= the model's, and the final
  E_strain / E_bend / B2G % / E_total (`_metrics`), wall time and simulated time.

Optional dependency (bench only): `newton` (PyPI; built on NVIDIA Warp, which we already use).

    .venv/bin/pip install newton==1.8.0   # or: pip install -e .[vbd]
    .venv/bin/python bench/bench_vbd.py --instances 3 --budget 120 --json runs/bench_vbd.json

World and material mapping (y up, metres, SI units; `physdrape.physics.Material()` defaults):

- Up axis / gravity: `ModelBuilder(up_axis=Axis.Y, gravity=(0, -9.81, 0))`; ours is E_grav = sum_i m_i g y_i.
- Rest shape: the template (`batch.garments.rest`) is given to `add_cloth_mesh`, so VBD's rest
  triangles (Dm^-1, rest areas) and rest edge lengths are the template's; the simulation then
  starts from the plain skinned garment (`InstanceInput.skinned`, as the oracle does) by
  overwriting the state's particle positions, at rest (v = 0).
- Mass: `density` = rho_A = 0.20022 kg/m^2 on the rest areas, lumped A/3 per vertex - exactly our
  m_i = sum_{f ni i} rho_A A_f / 3.
- Membrane: VBD's triangle element is a stable Neo-Hookean membrane
  psi = (mu/2)(tr(F^T F) - 2) + (lambda'/2)(J - alpha)^2 with lambda' = lambda + mu, alpha = 1 + mu/lambda',
  per unit rest AREA, where (mu, lambda) are the triangle's `tri_ke`, `tri_ka`. Its small-strain
  expansion is mu |eps|^2 + (lambda/2) tr(eps)^2, the same as our StVK psi = mu ||G||^2 + (lambda/2) tr(G)^2
  per unit rest VOLUME t*A. So tri_ke = mu*t = 2.36e4 * 4.7e-4 = 11.09 N/m and
  tri_ka = lambda*t = 4.44e4 * 4.7e-4 = 20.87 N/m: identical to first order; they differ at large
  strain (StVK's energy grows faster in stretch and loses its resistance under strong compression,
  where the Neo-Hookean one resists inversion) - we always measure with OUR StVK energy.
- Bending: VBD's hinge energy is (k_e l_e / 2)(theta - theta_0)^2 with k_e = the edge's
  `edge_ke`, l_e its rest length, theta the signed dihedral angle; ours is
  k_b l_e^2 / (4(A_0 + A_1)) * theta^2 / 2 with a FLAT rest angle. We set per edge (after
  `finalize`, before the solver is built) edge_ke_e = cloth.bend_stiffness_h / l_e
  (= k_b l_e / (4(A_0 + A_1)), k_b = 3.96e-5 J) and theta_0 = 0: the same energy.
- Contact: our penalty is k_c ReLU(eps - d)^3 (k_c = 2.5e3, eps = 2 mm) at vertices and face
  centroids; VBD's body-particle contact is a vertex-only quadratic penalty
  (ke/2)(r - d)^2 with r = particle radius + shape margin. We use r = eps = 2 mm (particle radius,
  margin 0), `--contact-ke` (default 1e3 N/m), the solver's contact damping `--contact-kd`, and
  NO friction (mu = 0: our static energy has none, so friction would change the equilibrium).
  A cubic penalty cannot be expressed; with either, a settled drape has its vertices within a
  fraction of a millimetre of d = eps. Detection (Newton's signed mesh query, `soft_contact_gap`)
  reaches `--contact-gap` beyond r; vertices deeper inside the body than that at X_init are not seen.
- Not in our energy, so switched off: self-contact (VBD's `particle_enable_self_contact=False`;
  the oracle and the model have none either), aerodynamic drag/lift.
- Damping (only to make a dynamic simulation settle; it does not change the equilibrium):
  `--tri-kd` / `--edge-kd` (VBD's per-element damping, objective Rayleigh-like terms on the rate of
  F^T F and of theta) and a global viscous velocity damping v <- v exp(-c dt), c = `--drag` [1/s],
  applied after every step.
- Time stepping: `--dt` 1/480 s, `--iterations` 10 VBD sweeps per step. Larger steps leave each
  step under-converged, and the unconverged steps pump strain energy into the drape (far more
  than gravity releases, with little kinetic energy): the simulation then settles well above the
  equilibrium. Check a change of `--dt` or `--iterations` by halving dt and doubling the
  iterations: the final energies should barely move.
- Times: the first-reach time is resolved to one check: after 1, 2, 4, 8, ... steps, then every
  `--check-every` simulated seconds.
- Not mappable: Newton is float32 (we evaluate energies in float64 on its positions).

    .venv/bin/python bench/bench_vbd.py --instances 1 --budget 30   # a quick look
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

INSTALL_HINT = ".venv/bin/pip install newton==1.8.0"

try:
    import newton
    import warp as wp
except ImportError as exc:  # optional, bench-only dependency
    print(f"bench_vbd.py needs the optional package `newton` (Newton's VBD cloth solver), not importable here "
          f"({exc}).\nInstall it with:\n    {INSTALL_HINT}", file=sys.stderr)
    sys.exit(2)

from physdrape.body.anny_body import get_anny_body
from physdrape.checkpoint import load_model
from physdrape.eval.evaluate import (
    Contact,
    EvalConfig,
    _metrics,
    _test_instances,
    run_model,
    total_energy,
)
from physdrape.eval.report import finite_or_none
from physdrape.model import Variant
from physdrape.physics import Material
from physdrape.physics.contact import DEFAULT_MARGIN
from physdrape.physics.forces import energy_terms

DEFAULT_CHECKPOINT = "src/physdrape/assets/models/cpu_default"


class VBDSim:
    """One instance in Newton: the garment (rest = template, start = X_init) and the static body."""

    def __init__(self, batch, args, material: Material) -> None:
        t0 = time.perf_counter()
        self.args = args
        rest = batch.garments.rest.detach().cpu().numpy().astype(np.float64)
        faces = batch.garments.faces.detach().cpu().numpy().astype(np.int64)
        x_init = batch.x_init.detach().cpu().numpy().astype(np.float32)
        body_verts = batch.bodies.verts[0].detach().cpu().numpy().astype(np.float32)
        body_faces = batch.bodies.faces.detach().cpu().numpy().astype(np.int32)

        builder = newton.ModelBuilder(up_axis=newton.Axis.Y, gravity=(0.0, -material.gravity, 0.0))
        builder.add_cloth_mesh(
            pos=wp.vec3(0.0, 0.0, 0.0), rot=wp.quat_identity(), scale=1.0, vel=wp.vec3(0.0, 0.0, 0.0),
            vertices=rest.tolist(), indices=faces.reshape(-1).tolist(), density=material.density,
            tri_ke=material.mu * material.thickness, tri_ka=material.lam * material.thickness, tri_kd=args.tri_kd,
            tri_drag=0.0, tri_lift=0.0, edge_ke=0.0, edge_kd=args.edge_kd, particle_radius=DEFAULT_MARGIN,
        )
        shape_cfg = newton.ModelBuilder.ShapeConfig(ke=args.contact_ke, kd=args.contact_kd, mu=0.0, margin=0.0,
                                                    density=0.0)
        body_mesh = newton.Mesh(body_verts, body_faces.reshape(-1), compute_inertia=False)
        builder.add_shape_mesh(body=-1, mesh=body_mesh, cfg=shape_cfg)  # static collider (no body)
        builder.color(include_bending=True)
        model = builder.finalize(device="cpu")
        if model.tri_count != len(faces):
            raise RuntimeError(f"Newton dropped {len(faces) - model.tri_count} degenerate triangles of the template")
        model.soft_contact_ke = args.contact_ke
        model.soft_contact_kd = args.contact_kd
        model.soft_contact_mu = 0.0
        model.shape_material_mu.fill_(0.0)

        # Bending: per-edge stiffness so that (k_e l_e / 2) theta^2 = our bend_stiffness_h theta^2 / 2; flat rest.
        edges = model.edge_indices.numpy()  # (E, 4): [opposite 0, opposite 1, edge v0, edge v1], -1 on the border
        rest_len = model.edge_rest_length.numpy()
        hinges = batch.cloth.hinges.detach().cpu().numpy()  # (H, 4): [shared edge v0, v1, opposite v2, v3]
        bend = batch.cloth.bend_stiffness.detach().cpu().numpy().astype(np.float64)
        ours = {(min(a, b), max(a, b)): k for (a, b), k in zip(hinges[:, :2].tolist(), bend.tolist())}
        props = model.edge_bending_properties.numpy()
        matched = 0
        for e, (o0, o1, a, b) in enumerate(edges.tolist()):
            k = ours.get((min(a, b), max(a, b))) if o0 >= 0 and o1 >= 0 else None
            props[e, 0] = 0.0 if k is None else k / max(float(rest_len[e]), 1e-12)
            matched += k is not None
        if matched != len(ours):
            raise RuntimeError(f"matched {matched} of our {len(ours)} hinges to Newton's edges")
        model.edge_bending_properties.assign(props)
        model.edge_rest_angle.zero_()
        self.model = model

        self.pipeline = newton.CollisionPipeline(model, broad_phase="nxn", soft_contact_gap=args.contact_gap)
        self.solver = newton.solvers.SolverVBD(model, iterations=args.iterations, particle_enable_self_contact=False,
                                               collision_pipeline=self.pipeline)
        self.control = model.control()
        self.x_init = x_init
        # One step on scratch states: Warp compiles (or loads cached) kernels on first launch; not timed.
        s0, s1 = self._fresh_states()
        self.solver.step(s0, s1, self.control, None, args.dt)
        self.state_0, self.state_1 = self._fresh_states()
        self.setup_s = time.perf_counter() - t0

    def _fresh_states(self):
        s0, s1 = self.model.state(), self.model.state()
        for s in (s0, s1):
            s.particle_q.assign(self.x_init)
            s.particle_qd.zero_()
        return s0, s1

    def step(self) -> None:
        args = self.args
        self.state_0.clear_forces()
        self.solver.step(self.state_0, self.state_1, self.control, None, args.dt)
        self.state_0, self.state_1 = self.state_1, self.state_0
        if args.drag > 0:
            qd = self.state_0.particle_qd.numpy()
            qd *= math.exp(-args.drag * args.dt)
            self.state_0.particle_qd.assign(qd)

    def positions(self, dtype) -> torch.Tensor:
        return torch.from_numpy(self.state_0.particle_q.numpy().astype(np.float64)).to(dtype)

    def speeds(self) -> tuple[float, float]:
        """(max, 99th percentile) vertex speed [m/s]."""
        v = np.sqrt((self.state_0.particle_qd.numpy().astype(np.float64) ** 2).sum(1))
        return float(v.max()), float(np.percentile(v, 99))


def energy_record(x: torch.Tensor, batch, contact: Contact) -> dict:
    """OUR total energy and its terms [J] at x: strain, bend, gravity, contact (= total - the others)."""
    with torch.no_grad():
        terms = {k: float(v[0]) for k, v in energy_terms(x, batch.cloth).items()}
    total = float(total_energy(x, batch, contact)[0])
    return {"energy": total, **terms, "contact": total - sum(terms.values())}


def simulate(batch, args, material: Material, target_energy: float, contact: Contact) -> dict:
    """Runs VBD on one instance; returns its numbers and (wall, sim time, energy, max speed) history."""
    sim = VBDSim(batch, args, material)
    dtype = batch.x_init.dtype
    steps_per_check = max(1, round(args.check_every / args.dt))
    checks_per_window = max(1, round(args.settle_window / (steps_per_check * args.dt)))
    history = [{"wall": 0.0, "sim_t": 0.0, **energy_record(sim.positions(dtype), batch, contact), "max_speed": 0.0,
                "p99_speed": 0.0}]
    wall, steps, reason = 0.0, 0, "budget"
    while True:
        # Checks after 1, 2, 4, 8, ... steps at first (the energy falls fastest there), then every steps_per_check.
        chunk = min(max(steps, 1), steps_per_check)
        t0 = time.perf_counter()
        for _ in range(chunk):
            sim.step()
        wall += time.perf_counter() - t0
        steps += chunk
        x = sim.positions(dtype)
        if not torch.isfinite(x).all():
            reason = "diverged (non-finite positions)"
            break
        speed, speed_p99 = sim.speeds()
        history.append({"wall": wall, "sim_t": steps * args.dt, **energy_record(x, batch, contact), "max_speed": speed,
                        "p99_speed": speed_p99})
        if args.verbose:
            h = history[-1]
            print(f"  [vbd] t_sim {h['sim_t']:.2f} s, wall {wall:.1f} s, E {h['energy']:.5g} J "
                  f"(strain {h['strain']:.4g}, bend {h['bend']:.3g}, grav {h['gravity']:.4g}, "
                  f"contact {h['contact']:.3g}), |v| max {speed:.3g} p99 {speed_p99:.3g} m/s", file=sys.stderr)
        if speed < args.settle_speed:
            reason = "settled (max |v| < settle speed)"
            break
        window = [h["energy"] for h in history if h["sim_t"] >= steps * args.dt - args.settle_window - 1e-9]
        if (steps * args.dt >= 2 * args.settle_window and len(window) > checks_per_window
                and max(window) - min(window) < args.settle_rel * abs(window[-1])):
            reason = "settled (energy flat)"
            break
        if wall >= args.budget:
            break
    x = sim.positions(dtype)
    final = _metrics(x, batch, contact) if torch.isfinite(x).all() else {}
    reached = next((h["wall"] for h in history if h["energy"] <= target_energy), math.inf)
    return {"vbd_setup_s": sim.setup_s, "vbd_wall_s": wall, "vbd_sim_s": steps * args.dt, "vbd_steps": steps,
            "vbd_reason": reason, "vbd_to_model_energy_s": reached, "vbd_final": final, "vbd_history": history}


def _write_json_atomic(path: str, payload: dict) -> None:
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    try:
        with os.fdopen(fd, "w") as handle:
            json.dump(payload, handle, indent=1)
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def build_parser() -> argparse.ArgumentParser:
    """The bench's flags, with the VBD settings and their defaults (also read by time_to_quality.py)."""
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--checkpoint", default=DEFAULT_CHECKPOINT)
    parser.add_argument("--instances", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--budget", type=float, default=120.0, help="VBD wall-time budget per instance [s]")
    parser.add_argument("--model-steps", type=int, default=15, help="the model's solver steps T")
    parser.add_argument("--repeats", type=int, default=3, help="timed model calls (median) after a warm-up")
    parser.add_argument("--dt", type=float, default=1.0 / 480.0,
                        help="VBD time step [s] (1/120 and 1/240 with 10 iterations pumped energy into the drape)")
    parser.add_argument("--iterations", type=int, default=10, help="VBD iterations per step")
    parser.add_argument("--check-every", type=float, default=0.05,
                        help="energy check period [simulated s] (after checks at 1, 2, 4, ... steps)")
    parser.add_argument("--settle-speed", type=float, default=5e-3, help="settled when max |v| < this [m/s]")
    parser.add_argument("--settle-rel", type=float, default=1e-3,
                        help="or settled when the energy varied by < this fraction over --settle-window")
    parser.add_argument("--settle-window", type=float, default=0.25, help="[simulated s]")
    parser.add_argument("--drag", type=float, default=5.0, help="global velocity damping rate c [1/s]")
    parser.add_argument("--tri-kd", type=float, default=1e-2, help="VBD membrane damping")
    parser.add_argument("--edge-kd", type=float, default=1e-5, help="VBD bending damping")
    parser.add_argument("--contact-ke", type=float, default=1e3, help="body contact stiffness [N/m]")
    parser.add_argument("--contact-kd", type=float, default=1e-2, help="body contact damping")
    parser.add_argument("--contact-gap", type=float, default=1e-2, help="contact detection reach beyond r [m]")
    parser.add_argument("--json", help="also write the per-instance numbers here (atomically)")
    parser.add_argument("--verbose", action="store_true", help="print every energy check")
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    torch.set_num_threads(1)
    wp.config.quiet = True
    wp.init()
    wp.set_device("cpu")
    material = Material()

    config = EvalConfig(instances=args.instances, seed=args.seed, oracle=False, threads=1)
    model, info = load_model(args.checkpoint, variant=Variant.FULL)
    print(f"checkpoint {info['path']} (step {info['step']}); {args.instances} instances, seed {args.seed}; "
          f"VBD (newton {newton.__version__}, warp {wp.__version__}, CPU): budget {args.budget} s, dt {args.dt:.4g} s, "
          f"{args.iterations} iterations, drag {args.drag}/s; torch threads {torch.get_num_threads()}")
    contact = Contact.of(model)
    instances = _test_instances(config, get_anny_body())
    rows = []
    for inst in instances:
        batch, _, skinned = inst.batch()  # (also the warm-up of the kinematic init)
        row = {"garment": inst.garment, "num_verts": inst.num_verts, "body": inst.body_index,
               "start_energy": float(total_energy(skinned, batch, contact)[0])}
        init_s = statistics.median(inst.batch()[1] for _ in range(args.repeats))
        run_model(model, batch, steps=args.model_steps)  # warm-up
        times, x = [], None
        for _ in range(args.repeats):
            x, wall = run_model(model, batch, steps=args.model_steps)
            times.append(wall)
        row["model_s"] = init_s + statistics.median(times)  # X_init + model, as a user pays
        row["model"] = _metrics(x, batch, contact)
        # VBD starts from the plain skinned garment, like the oracle (the pull-back is the model's).
        row.update(simulate(dataclasses.replace(batch, x_init=skinned), args, material, row["model"]["energy_total"],
                            contact))
        rows.append(row)
        brief = {k: v for k, v in row.items() if k != "vbd_history"}
        print(json.dumps(finite_or_none(brief)), file=sys.stderr)
        del batch

    def fmt_time(r):
        t = r["vbd_to_model_energy_s"]
        return f"{t:.3g}" if math.isfinite(t) else f"not reached (≥{r['vbd_wall_s']:.3g})"

    def final(r, key):
        return r["vbd_final"].get(key, math.nan)

    print()
    print(f"| instance | verts | model T={args.model_steps} wall [s] | model E_total [J] | VBD wall to model's E [s] "
          f"| VBD wall [s] | VBD sim [s] | VBD end | VBD E_strain | VBD E_bend | VBD B2G % | VBD E_total [J] "
          f"| model E_strain | model E_bend | model B2G % |")
    print("|---" * 15 + "|")
    for r in rows:
        m = r["model"]
        print(f"| {r['garment']} / body {r['body']} | {r['num_verts']} | {r['model_s']:.3g} | {m['energy_total']:.4g} "
              f"| {fmt_time(r)} | {r['vbd_wall_s']:.3g} | {r['vbd_sim_s']:.3g} | {r['vbd_reason']} "
              f"| {final(r, 'strain'):.4g} | {final(r, 'bend'):.3g} | {final(r, 'b2g_percent'):.3g} "
              f"| {final(r, 'energy_total'):.4g} | {m['strain']:.4g} | {m['bend']:.3g} | {m['b2g_percent']:.3g} |")

    def med(values):
        values = list(values)
        return statistics.median(values) if values else math.nan

    reached = [r for r in rows if math.isfinite(r["vbd_to_model_energy_s"])]
    to_model = med(r["vbd_to_model_energy_s"] for r in rows)  # inf entries count as "above"
    print(f"| **median** ({len(rows)}) | {med(r['num_verts'] for r in rows):.0f} | {med(r['model_s'] for r in rows):.3g} "
          f"| {med(r['model']['energy_total'] for r in rows):.4g} "
          f"| {f'{to_model:.3g}' if math.isfinite(to_model) else 'not reached'} ({len(reached)}/{len(rows)} reached) "
          f"| {med(r['vbd_wall_s'] for r in rows):.3g} | {med(r['vbd_sim_s'] for r in rows):.3g} "
          f"| {sum(r['vbd_reason'].startswith('settled') for r in rows)}/{len(rows)} settled "
          f"| {med(final(r, 'strain') for r in rows):.4g} | {med(final(r, 'bend') for r in rows):.3g} "
          f"| {med(final(r, 'b2g_percent') for r in rows):.3g} | {med(final(r, 'energy_total') for r in rows):.4g} "
          f"| {med(r['model']['strain'] for r in rows):.4g} | {med(r['model']['bend'] for r in rows):.3g} "
          f"| {med(r['model']['b2g_percent'] for r in rows):.3g} |")
    print()
    print(f"E(skinned start of VBD) median {med(r['start_energy'] for r in rows):.4g} J; VBD wall excludes setup "
          f"(median {med(r['vbd_setup_s'] for r in rows):.3g} s: model build, colouring, kernel load, one warm-up step) "
          f"and the energy checks; VBD speed {med(r['vbd_wall_s'] / max(r['vbd_sim_s'], 1e-9) for r in rows):.3g} "
          f"s wall per simulated s (median).")
    if args.json:
        _write_json_atomic(args.json, finite_or_none({"checkpoint": info, "config": vars(args),
                                                        "newton": newton.__version__, "instances": rows}))
    return 0


if __name__ == "__main__":
    sys.exit(main())

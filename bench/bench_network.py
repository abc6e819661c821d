"""The network's cost per garment: one GNN pass, and its graph inputs, no physics, one thread.

Run: .venv/bin/python bench/bench_network.py [--repeats 15] [--verts 4000]
    [--sizes 32x4 32x9l4 48x9l4 64x9l4 32x17l4] [--compile] [--out results/bench_network]
(a size is latent x blocks, optionally l + coarse graph levels: with levels the blocks walk
V-cycles over the coarse graphs, `physdrape.model.gnn.level_schedule`; a trailing g adds the
garment's summary after every block, `ModelConfig.global_context`, e.g. 32x9l4g).

The garment is an open tube of about `--verts` vertices around an icosphere body of ~10k
vertices. Every size is timed in one run, interleaved round by round so that a change in the
machine's load hits all of them alike; the table gives each size's median over the rounds, its
ratio to the first size, the parameters, the graph reach (the mesh edges one network pass
spans, `reach`) and, apart, the graph inputs (body query, node and edge features; the same work
for every size) and what `displacement: preconditioned` adds to a pass: the solver's
preconditioner built at X_init and applied to the output once (the same for every size). With
`--compile` every size is also timed with its network compiled by `torch.compile`
(`EncodeProcessDecode.compile_network`, the same weights; compiled by the warm-up, outside the
timing; each network a graph of its own for torch._dynamo, whose limit of graphs per function
the script raises to fit), and every row also times a training pass: the network's forward and the backward of a
loss on its output (what a training step spends in the network). Writes
<out>.md and <out>.json with the command, the commit and the load average.
"""

from __future__ import annotations

import argparse
import os
import shlex
import statistics
import sys
import time

import torch
from bench_model import problem
from report import source_lines, write_report

from physdrape.model import ModelConfig, PhysDrape
from physdrape.model.gnn import level_schedule
from physdrape.provenance import provenance


def reach(blocks: int, levels: int) -> int:
    """Mesh edges spanned by one pass: a level-l block passes a message about 2^l mesh edges."""
    return sum(2 ** level for level in level_schedule(blocks, levels))


def parse(size: str) -> tuple[int, int, int, bool]:
    """(latent, blocks, levels, garment summaries) of a size such as 32x9l4 or 32x9l4g."""
    summaries = size.endswith("g")
    dims, _, levels = size.removesuffix("g").partition("l")
    latent, blocks = (int(v) for v in dims.split("x"))
    return latent, blocks, int(levels or 0), summaries


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=15)
    parser.add_argument("--verts", type=int, default=4000)
    parser.add_argument("--sizes", nargs="+", default=["32x4", "32x9l4", "48x9l4", "64x9l4", "32x17l4"])
    parser.add_argument("--compile", action="store_true", help="also time each size compiled (torch.compile)")
    parser.add_argument("--out", default="results/bench_network")
    args = parser.parse_args()
    torch.set_num_threads(1)
    if args.compile:  # every size's network is a graph of its own (two with the backward): more than dynamo's default 8
        torch._dynamo.config.recompile_limit = 8 * len(args.sizes)
    batch = problem(1, args.verts)
    models = {}
    for size in args.sizes:
        latent, blocks, levels, summaries = parse(size)
        torch.manual_seed(0)
        model = PhysDrape(ModelConfig(latent=latent, blocks=blocks, levels=levels, global_context=summaries)).eval()
        model.accumulate_statistics(batch)
        models[size] = model
        if args.compile:
            compiled = PhysDrape(model.config).eval()
            compiled.load_state_dict(model.state_dict())
            compiled.gnn.compile_network()
            models[f"{size} compiled"] = compiled

    def network(model: PhysDrape) -> tuple[float, float, float]:
        """(graph inputs, GNN pass, GNN forward and backward) wall times [ms]."""
        with torch.no_grad():
            t0 = time.perf_counter()
            nodes, edges, graph = model.graph_inputs(batch)
            t1 = time.perf_counter()
            nodes, edges = model.node_normalizer(nodes), model.edge_normalizer(edges)
            t2 = time.perf_counter()
            model.gnn(nodes, edges, graph)
            t3 = time.perf_counter()
        model.gnn.zero_grad(set_to_none=True)
        t4 = time.perf_counter()
        model.gnn(nodes, edges, graph).square().sum().backward()
        t5 = time.perf_counter()
        return 1e3 * (t1 - t0), 1e3 * (t3 - t2), 1e3 * (t5 - t4)

    solver = next(iter(models.values())).solver

    def preconditioned() -> float:
        """The preconditioned displacement's extra work: C at X_init, applied once [ms]."""
        t0 = time.perf_counter()
        precondition = solver.preconditioner(batch.x_init, batch.cloth, bodies=batch.bodies, body_index=batch.body_index)
        precondition(batch.x_init)
        return 1e3 * (time.perf_counter() - t0)

    for model in models.values():
        network(model)  # warm-up: coarse graphs are built and cached per topology; compiled networks compile
    preconditioned()
    inputs = {size: [] for size in models}
    gnn = {size: [] for size in models}
    training = {size: [] for size in models}
    preconditioner = []
    for _ in range(args.repeats):
        for size, model in models.items():
            a, b, c = network(model)
            inputs[size].append(a)
            gnn[size].append(b)
            training[size].append(c)
        preconditioner.append(preconditioned())
    first = statistics.median(gnn[args.sizes[0]])
    rows = []
    for size, model in models.items():
        latent, blocks, levels, summaries = parse(size.split()[0])
        median = statistics.median(gnn[size])
        rows.append({"size": size, "compiled": size.endswith("compiled"), "latent": latent, "blocks": blocks,
                     "levels": levels, "global_context": summaries,
                     "training_median_ms": statistics.median(training[size]),
                     "params": sum(p.numel() for p in model.parameters()), "reach_edges": reach(blocks, levels),
                     "inputs_median_ms": statistics.median(inputs[size]), "gnn_median_ms": median,
                     "gnn_min_ms": min(gnn[size]), "gnn_max_ms": max(gnn[size]), "gnn_ratio_to_first": median / first})
    command = shlex.join(["python", *sys.argv])
    record = {"command": command, "provenance": provenance(), "load_average": os.getloadavg(),
              "garment_verts": batch.garments.num_verts, "body_verts": batch.bodies.num_verts,
              "threads": 1, "repeats": args.repeats, "rows": rows,
              "preconditioner_median_ms": statistics.median(preconditioner),
              "preconditioner_min_ms": min(preconditioner), "preconditioner_max_ms": max(preconditioner)}
    lines = ["# The network's cost per garment (GNN pass and graph inputs, no physics, 1 thread)", "",
             *source_lines(command, record["provenance"]),
             f"Garment: {record['garment_verts']} vertices; body: {record['body_verts']} vertices; "
             f"median of {args.repeats} interleaved rounds; load average "
             + ", ".join(f"{v:.2f}" for v in record["load_average"]), "",
             "| size (D×L, levels; summaries: `global_context`) | params | reach [mesh edges] | GNN median [ms] "
             "| GNN min–max [ms] | GNN ratio | forward + backward median [ms] | graph inputs median [ms] |",
             "|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        lines.append(f"| {r['latent']}×{r['blocks']}, {r['levels']}{', summaries' if r['global_context'] else ''}"
                     f"{', compiled' if r['compiled'] else ''} | "
                     f"{r['params']:,} | {r['reach_edges']} | "
                     f"{r['gnn_median_ms']:.1f} | {r['gnn_min_ms']:.1f}–{r['gnn_max_ms']:.1f} | "
                     f"{r['gnn_ratio_to_first']:.2f} | {r['training_median_ms']:.1f} | {r['inputs_median_ms']:.1f} |")
    lines += ["", ("The preconditioned displacement (`model.displacement: preconditioned`) adds to every size the "
                   "two-level solver's preconditioner at X_init, built and applied once: median "
                   f"{record['preconditioner_median_ms']:.1f} ms ({record['preconditioner_min_ms']:.1f}–"
                   f"{record['preconditioner_max_ms']:.1f}).")]
    write_report(args.out, lines, record)


if __name__ == "__main__":
    main()

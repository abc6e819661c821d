"""The training loop: self-supervised, seeded, checkpointed, resumable, data-parallel.

Every step draws the global batch's sample seeds from one generator shared by all ranks; rank r
builds samples [r·b, (r+1)·b) of them, so a run on R processes with local batch b sees exactly the
samples of a one-process run with batch R·b, and gradients (averaged by DDP) agree with it.

The model trains on the trainer's device: the source builds each batch (on the CPU) and the
trainer moves it there. Weights are initialised on the CPU before the move, so a seed gives the
same initial model on every device; the held-out validation runs on the CPU.
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Protocol

import torch
import torch.distributed as dist

from physdrape import checkpoint as ckpt
from physdrape.atomic import write_text
from physdrape.config_io import to_mapping
from physdrape.devices import resolve_device
from physdrape.model import ModelConfig, PhysDrape
from physdrape.model.stretching_solver import SolverKind
from physdrape.physics.metrics import b2g_percent
from physdrape.progress import progress_bar
from physdrape.train.data import DataConfig, TrainingBatch
from physdrape.train.loss import LossConfig, drape_loss, lookahead_target
from physdrape.train.node_inputs_memo import NodeInputsMemo


class SampleSource(Protocol):
    """Builds a batch of draping problems, each sample fully determined by its seed, and names a
    fixed validation set (empty: no held-out curve)."""

    def make_batch(self, seeds: list[int]) -> TrainingBatch: ...

    def validation(self) -> list[TrainingBatch]: ...


@dataclass(frozen=True)
class OptimConfig:
    """steps: optimiser steps in all; batch_size: global batch (garments per step, all ranks);
    lr: Adam's initial learning rate (paper 5e-5), decayed exponentially to lr·lr_final_ratio;
    grad_clip: max global gradient norm; seed: of the sample stream and the initial weights;
    checkpoint_every / log_every: in steps; validate_every: steps between held-out validations
    (`physdrape.train.validation`, on the source's validation set; 0 = never); keep_checkpoints:
    newest checkpoints kept;
    init_from: a checkpoint (directory with model.safetensors + config.json, or a run directory)
    whose weights and input statistics start a fresh run instead of random weights and the
    statistics warm-up (fine-tuning); "" = none. Ignored on --resume."""

    steps: int = 1000
    batch_size: int = 4
    lr: float = 5e-5
    lr_final_ratio: float = 0.1
    grad_clip: float = 1.0
    seed: int = 0
    checkpoint_every: int = 100
    log_every: int = 10
    validate_every: int = 0
    keep_checkpoints: int = 3
    init_from: str = ""

    def __post_init__(self) -> None:
        if self.steps < 1 or self.batch_size < 1 or not self.lr > 0 or not 0 < self.lr_final_ratio <= 1:
            raise ValueError("need steps ≥ 1, batch_size ≥ 1, lr > 0 and 0 < lr_final_ratio ≤ 1")


@dataclass(frozen=True)
class TrainConfig:
    """A training run: model, loss, optimiser and data sections.

    dtype: of the network's parameters ("float32" or "float64"); the physics runs in the dtype
    of the source's garments. The data section configures `DrapeSource` (the trainer itself
    takes whatever `SampleSource` it is given).
    """

    dtype: str = "float32"
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    data: DataConfig = field(default_factory=DataConfig)


def _world() -> tuple[int, int]:
    if dist.is_available() and dist.is_initialized():
        return dist.get_rank(), dist.get_world_size()
    return 0, 1


def _draw_seeds(generator: torch.Generator, count: int) -> list[int]:
    return torch.randint(0, 2**62, (count,), generator=generator, dtype=torch.int64).tolist()


class Trainer:
    """Runs `TrainConfig` on a `SampleSource`, writing checkpoints, metrics.jsonl and TensorBoard
    scalars under `run_dir`. Call `run(resume=True)` to continue from the latest checkpoint.

    device: where the model trains, "cpu" (the default), "cuda" or "cuda:N"
    (`physdrape.devices.resolve_device`; a DeviceError says how to fix an unmet CUDA request).
    compile_network: the network's forward and backward compiled by `torch.compile`
    (`EncodeProcessDecode.compile_network`: compiled at the first step)."""

    def __init__(self, config: TrainConfig, source: SampleSource, run_dir: str | os.PathLike, *, extra_config: dict | None = None,
                 progress: bool = True, tensorboard: bool = True, device: str | torch.device = "cpu",
                 compile_network: bool = False) -> None:
        self.device = resolve_device(device)
        self.config = config
        self.source = source
        self.run_dir = Path(run_dir)
        self.extra_config = extra_config or {}
        self.progress = progress
        self.tensorboard = tensorboard
        self.rank, self.world = _world()
        if config.optim.batch_size % self.world:
            raise ValueError(f"batch_size {config.optim.batch_size} is not divisible by the {self.world} processes")
        torch.manual_seed(config.optim.seed)
        if config.dtype not in ("float32", "float64"):
            raise ValueError(f"TrainConfig.dtype must be 'float32' or 'float64', got {config.dtype!r}")
        self.model = PhysDrape(config.model).to(getattr(torch, config.dtype)).to(self.device)
        if compile_network:
            self.model.gnn.compile_network()
        self.node_inputs = NodeInputsMemo(self.model)  # the network's inputs at each instance's X_init, made once
        self.generator = torch.Generator().manual_seed(config.optim.seed)
        self.step = 0
        self.ddp = None
        if self.world > 1:
            self.ddp = torch.nn.parallel.DistributedDataParallel(
                self.model, device_ids=[self.device.index] if self.device.type == "cuda" else None,
                find_unused_parameters=config.model.variant.value != "full"
            )
        self.distill = None
        if config.loss.distill_weight > 0:
            if not config.optim.init_from:
                raise ValueError("loss.distill_weight > 0 distills the network the run starts from: set "
                                 "optim.init_from to that checkpoint or run directory")
            from physdrape.train.distill import PassesTeacher

            self.distill = PassesTeacher(config.optim.init_from, config.loss.distill_passes, self.device)
        self.optimizer = torch.optim.Adam(self.model.parameters(), lr=config.optim.lr)
        decay = math.log(config.optim.lr_final_ratio) / config.optim.steps
        self.scheduler = torch.optim.lr_scheduler.LambdaLR(self.optimizer, lambda s: math.exp(decay * s))

    # ----------------------------------------------------------------------------- state
    def resolved_config(self) -> dict:
        return {"train": to_mapping(self.config), **self.extra_config}

    def save(self) -> Path | None:
        if self.rank != 0:
            return None
        tensors, meta = ckpt.optimizer_to_tensors(self.optimizer)
        tensors["rng.sample_stream"] = self.generator.get_state()
        tensors["rng.torch"] = torch.get_rng_state()
        meta.update(step=self.step, scheduler=self.scheduler.state_dict())
        return ckpt.save_checkpoint(self.run_dir, self.step, self.model, self.resolved_config(), train_tensors=tensors,
                                    train_meta=meta, keep=self.config.optim.keep_checkpoints)

    def load(self, path: Path) -> None:
        weights, _ = ckpt.read_checkpoint(path)
        self.model.load_state_dict(weights)
        tensors, meta = ckpt.read_train_state(path)
        self.optimizer.load_state_dict(ckpt.optimizer_from_tensors(tensors, meta))
        self.scheduler.load_state_dict(meta["scheduler"])
        self.generator.set_state(tensors["rng.sample_stream"])
        torch.set_rng_state(tensors["rng.torch"])
        self.step = int(meta["step"])

    def init_weights(self, checkpoint: str | os.PathLike) -> None:
        """Start from another checkpoint's model weights (input statistics included). Kept at this
        run's initial values instead: the solver's η and γ when the checkpoint's solver is of
        another kind (their meaning differs: a compliance in m/N vs a fraction of a preconditioned step),
        and the decoder's last layer when `model.zero_init_output` is set (the fine-tune then
        starts from the drape without the network and takes the checkpoint's features); and the
        look-back stage (`model.look_back_blocks`) when the checkpoint has none (its decoder starts
        at zero, so the fine-tune starts from the checkpoint's drape), and the processor blocks
        beyond the checkpoint's (`model.mesh_blocks`, which start as the identity: likewise), and the
        garments' summaries (`model.global_context`, which start at zero: likewise)."""
        weights, config = ckpt.read_checkpoint(checkpoint)
        own = self.model.state_dict()
        keep = []
        theirs = config.get("train", {}).get("model", {}).get("solver", SolverKind.EXPLICIT.value)
        if theirs != self.model.config.solver.value:
            keep += [k for k in own if k.startswith("solver.")]
        if self.model.config.zero_init_output:
            last = f"gnn.decoder.{len(self.model.gnn.decoder) - 1}."
            keep += [k for k in own if k.startswith(last)]
        added = tuple(f"gnn.blocks.{i}." for i in range(self.model.config.blocks, len(self.model.gnn.blocks)))
        keep += [k for k in own if k.startswith(("gnn.look_back_", "gnn.global_mlps.", *added)) and k not in weights]
        weights = {**weights, **{k: own[k] for k in keep}}
        try:
            self.model.load_state_dict({k: v.to(own[k].dtype) if k in own else v for k, v in weights.items()})
        except RuntimeError as exc:
            raise ckpt.CheckpointError(
                f"optim.init_from {checkpoint} does not fit this run's model (its model section: "
                f"{config.get('train', {}).get('model')}); use the same latent, blocks, "
                f"levels and variant: {exc}") from exc

    def _truncate_metrics(self) -> None:
        """Drop metric and validation lines logged after the checkpoint we resume from (they will be redone)."""
        for path in (self.run_dir / "metrics.jsonl", self.run_dir / "validation.jsonl"):
            if self.rank == 0 and path.is_file():
                kept = [line for line in path.read_text().splitlines() if line and json.loads(line)["step"] <= self.step]
                write_text(path, "".join(line + "\n" for line in kept))

    # ----------------------------------------------------------------------------- loop
    def _local_batch(self) -> TrainingBatch:
        seeds = _draw_seeds(self.generator, self.config.optim.batch_size)
        local = self.config.optim.batch_size // self.world
        sample = self.source.make_batch(seeds[self.rank * local:(self.rank + 1) * local])
        if sample.drape.device != self.device:
            sample = replace(sample, drape=sample.drape.to(self.device),
                             teacher=None if sample.teacher is None else sample.teacher.to(self.device))
        return self.node_inputs.attach(sample)

    def warm_up_normalizers(self) -> None:
        """Statistics-only warm-up (no optimiser steps); ranks all-reduce their sums."""
        for _ in range(self.config.model.normalizer_accumulations):
            self.model.accumulate_statistics(self._local_batch().drape)
        if self.world > 1:
            for norm in (self.model.node_normalizer, self.model.edge_normalizer):
                for name in ("count", "sum", "sum_squares"):
                    dist.all_reduce(getattr(norm, name))

    def train_step(self, *, measure: bool = True) -> dict[str, float]:
        """One optimiser step; returns the loss, its terms and the optimiser's state. measure: also
        the batch's B2G % (a body query of every face's centroid: `run` asks for it at the steps it
        logs)."""
        model = self.ddp or self.model
        model.train()
        sample = self._local_batch()
        batch = sample.drape
        distill = None if self.distill is None else self.distill.drapes(sample)
        out = model(batch)
        lookahead = None
        if self.config.loss.lookahead_weight > 0:
            lookahead = lookahead_target(out.x, batch.cloth, batch.bodies, batch.body_index, self.config.loss,
                                         self.config.model)
        loss, terms = drape_loss(out.x, batch.cloth, batch.bodies, batch.body_index, self.config.loss, batch.x_init,
                                 contact_stiffness=self.config.model.contact_stiffness, margin=self.config.model.margin,
                                 teacher=sample.teacher, lookahead=lookahead, earlier_passes=out.earlier_passes,
                                 distill=distill)
        self.optimizer.zero_grad(set_to_none=True)
        loss.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(self.model.parameters(), self.config.optim.grad_clip)
        self.optimizer.step()
        self.scheduler.step()
        self.step += 1
        measured = {}
        if measure:
            with torch.no_grad():
                b2g = b2g_percent(out.x.detach(), batch.garments, batch.bodies, batch.body_index).mean()
            measured["b2g_percent"] = float(b2g)
        return {"loss": float(loss.detach()), **{k: float(v) for k, v in terms.items()}, **measured,
                "grad_norm": float(grad_norm), "lr": self.scheduler.get_last_lr()[0], "eta": float(self.model.solver.eta.detach()),
                "gamma": float(self.model.solver.gamma.detach()), "delta": float(self.model.handler.delta.detach())}

    def _logs(self, step: int) -> bool:
        """Whether `run` writes the record of `step` to metrics.jsonl and TensorBoard."""
        return step % self.config.optim.log_every == 0 or step == self.config.optim.steps

    def _validate(self, validator, writer, bar=None) -> None:
        """One held-out validation (`physdrape.train.validation`), appended to validation.jsonl
        and TensorBoard's val/ scalars, and a line under the progress bar: the held-out energy gaps
        the network leaves (1 at X_init, 0 at the teacher's drape), the curve that shows learning
        where the training loss swings from sample to sample."""
        t0 = time.perf_counter()
        record = {"step": self.step, **validator(self.model), "wall_s": 0.0}
        record["wall_s"] = time.perf_counter() - t0
        with open(self.run_dir / "validation.jsonl", "a") as handle:
            handle.write(json.dumps(record) + "\n")
        if writer is not None:
            for key, value in record.items():
                if key != "step":
                    writer.add_scalar(f"val/{key}", value, self.step)
        if bar is not None:
            gaps = ", ".join(f"{row} {record[f'{row}/energy_gap']:.3f}" for row in ("gnn", "t3", "t15")
                             if f"{row}/energy_gap" in record)
            if gaps:
                bar.write(f"step {self.step}: held-out energy gap (1 = X_init, 0 = teacher): {gaps}", file=sys.stderr)

    def run(self, *, resume: bool = False, until: int | None = None) -> list[dict]:
        """Train to `optim.steps` (or stop early at step `until`, as an interruption would);
        with resume, continue from run_dir's latest checkpoint."""
        latest = ckpt.latest_checkpoint(self.run_dir) if resume else None
        if latest is not None:
            self.load(latest)
            self._truncate_metrics()
        elif self.step == 0 and self.config.optim.init_from:
            self.init_weights(self.config.optim.init_from)
        elif self.step == 0:
            self.warm_up_normalizers()
        writer = None
        if self.rank == 0 and self.tensorboard:
            from torch.utils.tensorboard import SummaryWriter

            writer = SummaryWriter(str(self.run_dir / "tensorboard"))
        bar = None
        if self.rank == 0 and self.progress:
            bar = progress_bar(total=self.config.optim.steps, initial=self.step, desc="train")
        history = []
        metrics_path = self.run_dir / "metrics.jsonl"
        self.run_dir.mkdir(parents=True, exist_ok=True)
        start = time.perf_counter()
        every = self.config.optim.validate_every
        validator = None
        if self.rank == 0 and every:
            from physdrape.train.validation import Validator

            validator = Validator(self.source.validation())
            if self.step == 0:
                self._validate(validator, writer, bar)
        try:
            stop = self.config.optim.steps if until is None else min(until, self.config.optim.steps)
            logged = None  # the last logged step's record: its B2G stays on the bar until the next
            while self.step < stop:
                record = self.train_step(measure=self._logs(self.step + 1))
                record["step"] = self.step
                record["wall_s"] = time.perf_counter() - start
                history.append(record)
                if self.rank == 0:
                    if self._logs(self.step):
                        logged = record
                        with open(metrics_path, "a") as handle:
                            handle.write(json.dumps(record) + "\n")
                        if writer is not None:
                            for key, value in record.items():
                                if key != "step":
                                    writer.add_scalar(key, value, self.step)
                    if bar is not None:
                        # shown at the bar's next redraw (a forced one per step would defeat its interval)
                        shown = {} if logged is None else {"b2g": f"{logged['b2g_percent']:.2f}%"}
                        bar.set_postfix(loss=f"{record['loss']:.4g}", **shown, refresh=False)
                        bar.update(1)
                if validator is not None and (self.step % every == 0 or self.step == stop):
                    self._validate(validator, writer, bar)
                if self.step % self.config.optim.checkpoint_every == 0 or self.step == stop:
                    self.save()
        finally:
            if bar is not None:
                bar.close()
            if writer is not None:
                writer.close()
        return history

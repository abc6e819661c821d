"""`physdrape train`: train a model (data-parallel under torchrun: gloo on CPU, NCCL on GPUs)."""

from __future__ import annotations

import argparse
import os
from dataclasses import replace

import torch

from physdrape.cli.common import CLIError, add_device_argument, process_device


def cmd_train(args: argparse.Namespace) -> int:
    """Train a model from a YAML run config into a run directory (resumable)."""
    import torch.distributed as dist

    from physdrape.config_io import load_config
    from physdrape.train.data import DrapeSource
    from physdrape.train.trainer import TrainConfig, Trainer

    if (args.config is None) == (args.recipe is None):
        raise CLIError("give either --config FILE (one run) or --recipe FILE (stages in order), not both")
    if args.recipe is not None:
        return _train_recipe(args)
    config = load_config(TrainConfig, args.config)
    if args.steps is not None:
        config = replace(config, optim=replace(config.optim, steps=args.steps))
    if args.init_from is not None:
        config = replace(config, optim=replace(config.optim, init_from=args.init_from))
    if args.threads:
        torch.set_num_threads(args.threads)
    if args.instances_only:
        if not config.data.instances:
            raise CLIError(f"--instances-only builds the instance cache that data.instances names, and {args.config} "
                           "names none: set data.instances to a folder (e.g. runs/instances)")
        DrapeSource(config.data, model=config.model)  # builds (or extends) the cache, then stops
        print(f"instance cache ready: {config.data.instances}")
        return 0
    distributed = int(os.environ.get("WORLD_SIZE", "1")) > 1
    if distributed:
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    try:
        trainer = Trainer(config, DrapeSource(config.data, model=config.model), args.run_dir,
                          device=process_device(args.device), compile_network=args.compile)
        trainer.run(resume=args.resume)
        if distributed:
            dist.barrier()  # no rank tears gloo down while another still talks to it
    finally:  # after an error or Ctrl-C the other ranks may be gone: no barrier then
        if distributed:
            dist.destroy_process_group()
    return 0


def _train_recipe(args: argparse.Namespace) -> int:
    """Train a recipe's stages in order (see `physdrape.train.recipe`)."""
    import shlex
    import sys

    from physdrape.train.data import DrapeSource
    from physdrape.train.recipe import run_recipe

    if args.steps is not None or args.init_from is not None or args.instances_only:
        raise CLIError("--steps, --init-from and --instances-only apply to one config (--config); a recipe's stages "
                       "set their own")
    if int(os.environ.get("WORLD_SIZE", "1")) > 1:
        raise CLIError("a recipe runs in one process; run its stages with --config under torchrun instead")
    if args.threads:
        torch.set_num_threads(args.threads)
    run_recipe(args.recipe, args.run_dir, source=lambda config: DrapeSource(config.data, model=config.model),
               command=shlex.join(["physdrape", *sys.argv[1:]]), resume=args.resume, device=args.device,
               compile_network=args.compile)
    return 0


def _interrupted(args, argv) -> str:
    """Where the run stands and the command that continues it."""
    import shlex

    again = argv if "--resume" in argv else [*argv, "--resume"]
    command = (f"physdrape {shlex.join(again)}" if int(os.environ.get("WORLD_SIZE", "1")) == 1
               else "the same torchrun command with --resume")
    return f"the checkpoints saved so far are kept in {args.run_dir}; resume with: {command}"


def add_parser(sub) -> None:
    """The `train` subcommand."""
    train = sub.add_parser("train", help="train a PhysDrape model (self-supervised, resumable)")
    train.add_argument("--config", help="YAML run config (see configs/quickstart.yaml, configs/global/)")
    train.add_argument("--recipe", help="YAML recipe: configs trained as consecutive stages, then shipped "
                       "(configs/recipes/shipped.yaml trains the bundled model)")
    train.add_argument("--run-dir", required=True, help="directory for checkpoints, metrics.jsonl, TensorBoard")
    train.add_argument("--resume", action="store_true", help="continue from the run directory's latest checkpoint")
    train.add_argument("--steps", type=int, help="override optim.steps")
    train.add_argument("--init-from", help="override optim.init_from: the checkpoint (or run directory) a new run "
                       "starts from, e.g. src/physdrape/assets/models/cpu_default to fine-tune the bundled model")
    train.add_argument("--instances-only", action="store_true", help="build (or extend) the config's instance cache "
                       "(data.instances) and stop, e.g. before starting several runs that share it")
    train.add_argument("--threads", type=int, default=0, help="torch threads per process (0: torch's default)")
    train.add_argument("--compile", action="store_true", help="run the network's forward and backward compiled by "
                       "torch.compile (compiled at the first step: tens of seconds)")
    add_device_argument(train)
    train.set_defaults(func=cmd_train, interrupted=_interrupted)

"""Run by test_distributed.py under torchrun: a few data-parallel steps, rank 0 saves the weights."""

import sys

import torch
import torch.distributed as dist
from safetensors.torch import save_file

from physdrape.model import ModelConfig
from physdrape.train.synthetic import SyntheticSource
from physdrape.train.trainer import OptimConfig, TrainConfig, Trainer

# float64: Adam turns rounding-level gradient differences near zero into visible steps in float32.
# The explicit solver: the two-level one's line search and restarts are discrete decisions, which
# can turn a rounding-level difference of the summation order into a visible one.
CONFIG = TrainConfig(
    dtype="float64",
    model=ModelConfig(latent=16, blocks=2, normalizer_accumulations=2, solver="explicit", eta=1e-3, gamma=0.9,
                      max_step=5e-3),
    optim=OptimConfig(steps=3, batch_size=4, lr=3e-3, checkpoint_every=100, seed=5),
)

if __name__ == "__main__":
    out = sys.argv[1]
    torch.set_num_threads(1)
    distributed = len(sys.argv) > 2 and sys.argv[2] == "ddp"
    if distributed:
        dist.init_process_group("gloo")
    trainer = Trainer(CONFIG, SyntheticSource(dtype=torch.float64), out + "/run", progress=False, tensorboard=False)
    trainer.run()
    if trainer.rank == 0:
        save_file({k: v.contiguous() for k, v in trainer.model.state_dict().items()}, out + "/weights.safetensors")
    if distributed:
        dist.barrier()  # no rank tears gloo down while another still talks to it
        dist.destroy_process_group()

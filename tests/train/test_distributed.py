"""A 2-process torchrun (gloo) run equals one process on the same global batch."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch
from safetensors.torch import load_file

WORKER = Path(__file__).with_name("ddp_worker.py")


@pytest.mark.slow
def test_two_process_torchrun_matches_one_process(tmp_path):
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    single, double = tmp_path / "single", tmp_path / "ddp"
    single.mkdir()
    double.mkdir()
    subprocess.run([sys.executable, str(WORKER), str(single)], check=True, env=env, timeout=300)
    subprocess.run(
        [sys.executable, "-m", "torch.distributed.run", "--standalone", "--nproc_per_node=2", str(WORKER), str(double), "ddp"],
        check=True, env=env, timeout=300,
    )
    one, two = load_file(single / "weights.safetensors"), load_file(double / "weights.safetensors")
    assert one.keys() == two.keys()
    # Sums run in another order on two processes: equal up to float64 rounding.
    for name in one:
        torch.testing.assert_close(two[name], one[name], rtol=1e-9, atol=1e-11, msg=lambda m: f"{name}: {m}")
    # The steps did move the weights well beyond that tolerance (else equality would prove nothing).
    sys.path.insert(0, str(WORKER.parent))
    from ddp_worker import CONFIG

    from physdrape.model import PhysDrape

    torch.manual_seed(CONFIG.optim.seed)
    init = PhysDrape(CONFIG.model).double().state_dict()
    assert max(float((one[k] - init[k]).abs().max()) for k in one if k.startswith("gnn.")) > 1e-3

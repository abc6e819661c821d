"""`physdrape eval` argument parsing and a tiny end-to-end run."""

from __future__ import annotations

import argparse
import json

import pytest
import torch

from physdrape.config_io import to_mapping
from physdrape.cli.eval import add_parser
from physdrape.model import ModelConfig, PhysDrape
from physdrape.checkpoint import save_checkpoint
from physdrape.train.trainer import TrainConfig


def tiny_checkpoint(root):
    torch.manual_seed(0)
    config = TrainConfig(model=ModelConfig(latent=8, blocks=1))
    return save_checkpoint(root, 1, PhysDrape(config.model), {"train": to_mapping(config)})


def parser():
    root = argparse.ArgumentParser(prog="physdrape")
    add_parser(root.add_subparsers(dest="command", required=True))
    return root


def test_flags_parse():
    args = parser().parse_args(["eval", "--checkpoint", "c", "--out", "o", "--instances", "3", "--seed", "7",
                                "--oracle-budget", "5", "--no-oracle", "--ablation", "gnn=a", "--ablation",
                                "gnn+solver=b", "--split-dir", "s", "--max-garments", "2", "--makehuman", "m",
                                "--no-oracle-refine", "--oracle-max-iters", "500", "--oracle-settle-steps", "30"])
    assert args.instances == 3 and args.seed == 7 and args.oracle_budget == 5.0 and args.no_oracle
    assert args.no_oracle_refine and args.makehuman_max_verts == 0 and args.oracle_max_iters == 500
    assert args.oracle_settle_steps == 30
    assert dict(args.ablation) == {"gnn": "a", "gnn+solver": "b"}
    assert args.split_dir == "s" and args.max_garments == 2 and args.makehuman == "m"


def test_bad_ablation_name_is_a_usage_error(capsys):
    with pytest.raises(SystemExit):
        parser().parse_args(["eval", "--checkpoint", "c", "--out", "o", "--ablation", "solver=x"])
    assert "NAME one of" in capsys.readouterr().err


@pytest.mark.parametrize("flags, message", [(["--instances", "0"], "instances must be ≥ 1"),
                                           (["--makehuman-max-verts", "-1"], "makehuman_max_verts must be ≥ 0"),
                                           (["--oracle-max-iters", "0"], "oracle_max_iters must be ≥ 1"),
                                           (["--oracle-settle-steps", "-1"], "oracle_settle_steps must be ≥ 0")])
def test_bad_flag_values_exit_2_with_the_message(tmp_path, capsys, flags, message):
    from physdrape.cli import main

    out = tmp_path / "out"
    assert main(["eval", "--checkpoint", str(tmp_path), "--out", str(out), *flags]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()  # nothing written


def test_tiny_protocol_runs_and_writes_both_files(tmp_path, monkeypatch, anny_body, tiny_split):
    import physdrape.body.anny_body as anny

    monkeypatch.setattr(anny, "get_anny_body", lambda *a, **k: anny_body)
    ckpt = tiny_checkpoint(tmp_path / "run")
    args = parser().parse_args(["eval", "--checkpoint", str(tmp_path / "run"), "--out", str(tmp_path / "out"),
                                "--instances", "2", "--max-garments", "2", "--no-oracle", "--split-dir", tiny_split])
    assert args.func(args) == 0
    results = json.loads((tmp_path / "out" / "eval.json").read_text())
    assert results["checkpoints"]["physdrape_t15"]["path"] == str(ckpt.resolve())
    assert results["sets"]["test"]["oracle"] is None
    assert "## Table 2" in (tmp_path / "out" / "eval.md").read_text()

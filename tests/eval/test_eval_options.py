"""`physdrape eval`'s instance-layout and reference-cache flags reach EvalConfig as documented."""

from __future__ import annotations

import argparse

import pytest

from physdrape.cli.eval import add_parser
from physdrape.eval.config import EvalConfig, default_reference_cache, reference_cache_dir


class Captured(Exception):
    """Raised by the stand-in for `evaluate` to hand back the config it was given."""


def config_of(monkeypatch, *flags: str) -> EvalConfig:
    import physdrape.eval.evaluate as evaluate_module

    def capture(checkpoint, config, **kwargs):
        raise Captured(config)

    monkeypatch.setattr(evaluate_module, "evaluate", capture)
    root = argparse.ArgumentParser(prog="physdrape")
    add_parser(root.add_subparsers(dest="command", required=True))
    args = root.parse_args(["eval", "--checkpoint", "c", "--out", "o", *flags])
    with pytest.raises(Captured) as caught:
        args.func(args)
    return caught.value.args[0]


def test_defaults_are_the_whole_test_split_once_and_the_default_cache(monkeypatch):
    config = config_of(monkeypatch)
    assert config.instances is None and config.poses_per_garment == 1
    assert config.reference_cache == "" and reference_cache_dir(config) == default_reference_cache()


def test_layout_and_cache_flags(monkeypatch, tmp_path):
    config = config_of(monkeypatch, "--instances", "4", "--poses-per-garment", "2", "--reference-cache",
                       str(tmp_path))
    assert (config.instances, config.poses_per_garment) == (4, 2)
    assert reference_cache_dir(config) == tmp_path
    assert reference_cache_dir(config_of(monkeypatch, "--no-reference-cache")) is None


def test_cache_flags_exclude_each_other(capsys):
    root = argparse.ArgumentParser(prog="physdrape")
    add_parser(root.add_subparsers(dest="command", required=True))
    with pytest.raises(SystemExit):
        root.parse_args(["eval", "--checkpoint", "c", "--out", "o", "--reference-cache", "d", "--no-reference-cache"])
    assert "not allowed with" in capsys.readouterr().err


def test_a_bad_pose_count_exits_2_with_the_message(tmp_path, capsys):
    from physdrape.cli import main

    out = tmp_path / "out"
    assert main(["eval", "--checkpoint", str(tmp_path), "--out", str(out), "--poses-per-garment", "0"]) == 2
    assert "poses_per_garment must be ≥ 1" in capsys.readouterr().err
    assert not out.exists()

"""Every field of every run configuration is read somewhere: a field nothing reads is a switch
that silently does nothing (a static scan of src/physdrape)."""

from __future__ import annotations

import ast
import dataclasses
import functools
import inspect
from pathlib import Path

import pytest

import physdrape
from physdrape.eval.evaluate import EvalConfig
from physdrape.model import ModelConfig
from physdrape.train.data import DataConfig
from physdrape.train.loss import LossConfig
from physdrape.train.trainer import OptimConfig, TrainConfig

CONFIGS = [ModelConfig, LossConfig, OptimConfig, TrainConfig, DataConfig, EvalConfig]
SOURCE = Path(physdrape.__file__).parent


def _reads(tree: ast.AST, skip: ast.AST | None) -> set[str]:
    """Attribute names read in `tree` (`obj.name`, `getattr(obj, "name", ...)`), outside `skip`."""
    names: set[str] = set()

    def visit(node: ast.AST) -> None:
        if node is skip:
            return
        if isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Load):
            names.add(node.attr)
        elif (isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "getattr"
              and len(node.args) >= 2 and isinstance(node.args[1], ast.Constant) and isinstance(node.args[1].value, str)):
            names.add(node.args[1].value)
        for child in ast.iter_child_nodes(node):
            visit(child)

    visit(tree)
    return names


@functools.cache
def _trees() -> dict[Path, ast.Module]:
    return {path.resolve(): ast.parse(path.read_text(), filename=str(path)) for path in sorted(SOURCE.rglob("*.py"))}


@functools.cache
def _file_reads(path: Path) -> frozenset[str]:
    return frozenset(_reads(_trees()[path], None))


def _reads_outside(cls) -> set[str]:
    """Attribute names read anywhere under src/physdrape except inside the definition of `cls`."""
    own_file = Path(inspect.getsourcefile(cls)).resolve()
    own_tree = _trees()[own_file]
    own_class = next(node for node in ast.walk(own_tree) if isinstance(node, ast.ClassDef) and node.name == cls.__name__)
    names = _reads(own_tree, own_class)
    for path in _trees():
        if path != own_file:
            names |= _file_reads(path)
    return names


def test_the_scan_skips_the_class_itself():
    """ModelConfig.__post_init__ reads `self.variant`; a scan of its own file without the class
    must not see that read."""
    own_file = Path(inspect.getsourcefile(ModelConfig)).resolve()
    tree = _trees()[own_file]
    own_class = next(node for node in ast.walk(tree) if isinstance(node, ast.ClassDef) and node.name == "ModelConfig")
    assert "variant" in _reads(own_class, None)
    assert "levels" not in _reads(tree, own_class)


@pytest.mark.parametrize("cls", CONFIGS, ids=lambda cls: cls.__name__)
def test_every_config_field_is_read(cls):
    assert dataclasses.is_dataclass(cls) and cls.__dataclass_params__.frozen
    unread = sorted(f.name for f in dataclasses.fields(cls) if f.name not in _reads_outside(cls))
    assert not unread, (f"{cls.__name__} fields never read under src/physdrape: {unread}; "
                        "use them or remove them (a config field must change what runs)")

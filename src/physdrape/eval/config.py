"""The evaluation's settings (`EvalConfig`) and where its oracle results are cached."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

from physdrape.pipeline import DEFAULT_DTYPE
from physdrape.user_cache import cache_root


def default_reference_cache() -> Path:
    """Where the oracle's results are cached by default: ~/.cache/physdrape/eval_reference."""
    return cache_root() / "eval_reference"


def reference_cache_dir(config: EvalConfig) -> Path | None:
    """The folder of `config`'s cached oracle results (None: caching off)."""
    if config.reference_cache is None:
        return None
    return Path(config.reference_cache).expanduser() if config.reference_cache else default_reference_cache()


@dataclass(frozen=True)
class EvalConfig:
    """instances: test instances N, the first N of the instance layout (`physdrape.eval.instances`:
    instance i is test garment i mod G in pose i div G); None: every test garment
    `poses_per_garment` times; poses_per_garment: bodies (shape and pose) per test garment when
    `instances` is None; seed: of the body shapes/poses; oracle: run the oracle; oracle_budget_s:
    its wall-time budget per instance [s]; oracle_tol: its residual tolerance; oracle_max_iters:
    its iteration cap; oracle_refine: also run the oracle from the PhysDrape (T=15) drape and
    measure against the better of the two; oracle_settle_steps: also run the oracle from the
    model's drape at this T (0: not), a drape settled further along the slow modes, from which the
    oracle can end in a lower equilibrium; the reference is then the lowest of the oracle results;
    reference_cache: folder of the cached oracle results
    from the skinned start ("": `default_reference_cache()`, None: no cache); split_dir /
    max_garments: the garment split ("" = default cache) and its first N test garments (0 = all);
    makehuman_dir: CC0 MakeHuman garments (.mhclo), "" = skip; makehuman_instances: bodies per
    MakeHuman garment; makehuman_max_verts: skip MakeHuman garments with more vertices (0 = no
    cap); dtype: of the garments, bodies and physics handed to the model
    ("float32"/"float64"; default: the API's, so the evaluation measures what `Draper` runs; the
    network keeps its own); threads: torch threads (0: torch's default)."""

    instances: int | None = None
    poses_per_garment: int = 1
    seed: int = 0
    oracle: bool = True
    oracle_budget_s: float = 60.0
    oracle_tol: float = 1e-2
    oracle_max_iters: int = 200
    oracle_refine: bool = True
    oracle_settle_steps: int = 60
    reference_cache: str | None = ""
    split_dir: str = ""
    max_garments: int = 0
    makehuman_dir: str = ""
    makehuman_instances: int = 1
    makehuman_max_verts: int = 0
    dtype: str = str(DEFAULT_DTYPE).removeprefix("torch.")
    threads: int = 1

    def __post_init__(self) -> None:
        if self.instances is not None and self.instances < 1:
            raise ValueError(f"EvalConfig.instances must be ≥ 1 (or None: the whole test split), got {self.instances}")
        if self.seed < 0:
            raise ValueError(f"EvalConfig.seed must be ≥ 0, got {self.seed}")
        if self.poses_per_garment < 1:
            raise ValueError(f"EvalConfig.poses_per_garment must be ≥ 1, got {self.poses_per_garment}")
        if self.makehuman_instances < 1:
            raise ValueError(f"EvalConfig.makehuman_instances must be ≥ 1, got {self.makehuman_instances}")
        if self.dtype not in ("float32", "float64"):
            raise ValueError(f"EvalConfig.dtype must be 'float32' or 'float64', got {self.dtype!r}")
        if self.makehuman_max_verts < 0:
            raise ValueError(f"EvalConfig.makehuman_max_verts must be ≥ 0 (0: no cap), got {self.makehuman_max_verts}")
        if self.oracle_max_iters < 1:
            raise ValueError(f"EvalConfig.oracle_max_iters must be ≥ 1, got {self.oracle_max_iters}")
        if self.oracle_settle_steps < 0:
            raise ValueError(f"EvalConfig.oracle_settle_steps must be ≥ 0 (0: no such oracle run), "
                             f"got {self.oracle_settle_steps}")
        if not self.oracle_budget_s > 0:
            raise ValueError(f"EvalConfig.oracle_budget_s must be > 0, got {self.oracle_budget_s}")

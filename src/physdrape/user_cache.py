"""Where PhysDrape keeps what it makes once and reads again: ~/.cache/physdrape.

Its folders: `anny_body/` (the Anny body's data, `body.anny_data`), `garment_split_seed*_v*/`
(the generated garment split, `garments.split`), `generated_garments/` (the CATEGORY:SEED
garments a drape asked for, `garments.generated_cache`) and `eval_reference/` (the evaluation's
oracle results, `eval.config`). Everything there can be deleted: it is made again when needed.
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["cache_root"]


def cache_root() -> Path:
    """The root of PhysDrape's cache: ~/.cache/physdrape."""
    return Path.home() / ".cache" / "physdrape"

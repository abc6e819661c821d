"""Every procedural garment by name: the tops (`garments.generator`), the trousers and shorts
(`garments.trousers`) and the outfits of a top over trousers (`garments.outfits`).

A name and a seed make one garment, the first of the seed's draws that passes validation; this is
what the CLI's `--category NAME --seed N` and a `NAME:N` garment spec drape.
"""

from __future__ import annotations

from physdrape.garments.generator import GarmentCategory, generate_valid_garment
from physdrape.garments.outfits import generate_valid_outfit
from physdrape.garments.trousers import TrousersKind, generate_valid_trousers

__all__ = ["TOPS", "LOWER", "OUTFIT", "CATEGORIES", "generate_valid"]

#: The tops' categories.
TOPS = tuple(c.value for c in GarmentCategory)
#: The lower-body families.
LOWER = tuple(k.value for k in TrousersKind)
#: A top over trousers or shorts, one two-piece garment.
OUTFIT = "outfit"
CATEGORIES = TOPS + LOWER + (OUTFIT,)


def generate_valid(category: str, seed: int, *, target_edge: float = 0.015, body=None):
    """The garment `category`:`seed` as (GarmentTemplate, attempt): the first parameter draw of the
    seed that passes validation (`GarmentError` when none of the generator's attempts does)."""
    if category in TOPS:
        return generate_valid_garment(category, seed, target_edge=target_edge, body=body)
    if category in LOWER:
        return generate_valid_trousers(category, seed, target_edge=target_edge, body=body)
    if category == OUTFIT:
        return generate_valid_outfit(seed, target_edge=target_edge, body=body)
    raise ValueError(f"unknown garment category {category!r}; choose one of {', '.join(CATEGORIES)}")

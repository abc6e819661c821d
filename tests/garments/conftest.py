"""Fixtures for the garment tests: the canonical body is built once per session."""

from pathlib import Path

import pytest

MAKEHUMAN_DIR = Path(__file__).resolve().parents[3] / "shared" / "data" / "makehuman_cc0"


@pytest.fixture(scope="session")
def body():
    from physdrape.garments.canonical import canonical_body

    return canonical_body()


@pytest.fixture(scope="session")
def small_batch(body):
    """One valid garment per category (seeded)."""
    from physdrape.garments.generator import GarmentCategory, generate_valid_garment

    return [generate_valid_garment(c, 1234 + i)[0] for i, c in enumerate(GarmentCategory)]

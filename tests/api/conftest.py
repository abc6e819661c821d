"""A Draper on the shared tiny test checkpoint (tests/conftest.py)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="session")
def draper(anny_body, tiny_checkpoint):
    from physdrape.api import Draper

    return Draper(tiny_checkpoint, steps=3, body=anny_body)

import pytest

from physdrape.geometry.garment import Garment
from physdrape.geometry.primitives import grid_sheet, open_cylinder


@pytest.fixture
def sheet() -> Garment:
    return Garment.from_mesh(*grid_sheet(5, 6, width=0.3, height=0.25), name="sheet")


@pytest.fixture
def tube() -> Garment:
    return Garment.from_mesh(*open_cylinder(5, 9, radius=0.12, length=0.3), name="tube")

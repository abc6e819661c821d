import pytest
from drape_cases import tube


@pytest.fixture
def two_tubes():
    return [tube(6, 16, 0.14, name="a"), tube(5, 13, 0.17, name="b")]

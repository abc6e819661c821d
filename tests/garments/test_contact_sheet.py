import pytest

from physdrape.garments import render_contact_sheet

pytestmark = pytest.mark.anny


def test_contact_sheet_png(tmp_path, small_batch):
    out = render_contact_sheet(small_batch[:2], tmp_path / "sheet.png", cols=2,
                               titles=[g.name for g in small_batch[:2]], dpi=60)
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000

"""The Anny data PhysDrape reads: the cached copy against Anny itself, and the phenotype weights
against Anny's own rule, to the bit."""

import dataclasses

import pytest
import torch

from physdrape.body import anny_data
from physdrape.body.anny_body import PHENOTYPE_NAMES


def _shapes(dtype: torch.dtype) -> torch.Tensor:
    """Random phenotypes, every anchor of each, and the range's ends."""
    g = torch.Generator().manual_seed(0)
    random = torch.rand(64, len(PHENOTYPE_NAMES), generator=g, dtype=torch.float64)
    anchors = torch.tensor([0.0, 1 / 3, 0.5, 2 / 3, 1.0], dtype=torch.float64)[:, None].expand(5, len(PHENOTYPE_NAMES))
    return torch.cat([random, anchors]).to(dtype)


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_phenotype_coefficients_are_annys(anny_body, dtype):
    from anny.models.phenotype import make_phenotype_anchors, phenotype_blendshape_weights

    data = anny_body._data
    shape = _shapes(dtype)
    theirs = phenotype_blendshape_weights(shape, list(PHENOTYPE_NAMES), make_phenotype_anchors(dtype),
                                          data.mask.to(dtype), extrapolate=False)
    theirs = theirs if data.projection is None else theirs @ data.projection.to(dtype)
    ours = anny_data.phenotype_coefficients(data, shape, PHENOTYPE_NAMES)
    assert ours.dtype == dtype and torch.equal(ours, theirs)
    assert bool((ours != ours[:1]).any())  # the shapes weigh the blendshapes differently


def test_the_cached_data_is_what_anny_gives(anny_body, tmp_path, monkeypatch):
    """Read back from a cache written by `load_anny_data`, the data equal those made from Anny
    (every tensor and label); a damaged cache file is made again."""
    made = anny_data._from_anny("anny", "anny", True)
    monkeypatch.setattr(anny_data, "cache_dir", lambda: tmp_path)
    anny_data.load_anny_data.cache_clear()
    try:
        first = anny_data.load_anny_data("anny", "anny", True)  # written here
        anny_data.load_anny_data.cache_clear()
        read = anny_data.load_anny_data("anny", "anny", True)  # read back
        for field in dataclasses.fields(anny_data.AnnyData):
            a, b = getattr(made, field.name), getattr(read, field.name)
            if isinstance(a, torch.Tensor):
                assert a.dtype == b.dtype and torch.equal(a, b), field.name
            else:
                assert a == b, field.name
        assert torch.equal(first.blend, read.blend)
        (tensors,) = tmp_path.glob("anny_anny_surface_*.safetensors")
        tensors.write_bytes(b"not a safetensors file")
        anny_data.load_anny_data.cache_clear()
        again = anny_data.load_anny_data("anny", "anny", True)
        assert torch.equal(again.template, made.template)
        assert anny_data._read(tensors.with_suffix("")) is not None  # written again
    finally:
        anny_data.load_anny_data.cache_clear()


def test_an_unwritable_cache_warns_and_drapes_on(anny_body, tmp_path, monkeypatch):
    """Where the cache cannot be written, the data still come (from Anny), with a warning that says
    where and how to fix it."""
    blocked = tmp_path / "not_a_folder"
    blocked.write_text("a file where the cache folder would go")
    monkeypatch.setattr(anny_data, "cache_dir", lambda: blocked / "anny_body")
    anny_data.load_anny_data.cache_clear()
    try:
        with pytest.warns(UserWarning, match="make that folder writable"):
            data = anny_data.load_anny_data("anny", "anny", True)
        assert torch.equal(data.template, anny_body._data.template)
    finally:
        anny_data.load_anny_data.cache_clear()


def test_an_unknown_rig_is_refused():
    with pytest.raises(ValueError, match="unknown Anny rig"):
        anny_data.load_anny_data("smpl", "anny", True)

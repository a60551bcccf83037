"""The body assets kept unpacked between runs: the same arrays as the package holds, and no
cache when it is turned off or cannot be written."""

import io
import lzma
from importlib import resources

import numpy as np

from solver.body import model


def _blob() -> bytes:
    return (resources.files("solver") / "data" / "makehuman_body.npz.xz").read_bytes()


def test_cached_assets_equal_the_packed_ones(tmp_path, monkeypatch):
    monkeypatch.setenv(model.CACHE_ENV, str(tmp_path))
    blob = _blob()
    with np.load(io.BytesIO(lzma.decompress(blob))) as data:
        packed = {k: data[k] for k in data.files}
    first = model._cached_assets(blob)  # unpacks and writes the cache
    (folder,) = tmp_path.iterdir()
    assert sorted(p.name for p in folder.glob("*.npy")) == sorted(f"{k}.npy" for k in packed)
    second = model._cached_assets(blob)  # maps it
    assert isinstance(second["target_deltas"], np.memmap)
    for key, value in packed.items():
        np.testing.assert_array_equal(first[key], value)
        np.testing.assert_array_equal(second[key], value)
        assert second[key].dtype == value.dtype


def test_no_cache_when_off_or_unwritable(tmp_path, monkeypatch):
    monkeypatch.setenv(model.CACHE_ENV, "off")
    assert model.asset_cache_dir() is None
    assets = model._cached_assets(_blob())
    assert assets["faces"].shape == (13378, 4)
    blocked = tmp_path / "file"
    blocked.write_text("not a folder")
    monkeypatch.setenv(model.CACHE_ENV, str(blocked / "cache"))
    assert model._cached_assets(_blob())["faces"].shape == (13378, 4)
    assert blocked.read_text() == "not a folder"

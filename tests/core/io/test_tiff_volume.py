import numpy as np
import pytest
import tifffile

from core.io import read_tiff_volume


def test_round_trip_with_geometry(tmp_path):
    data = np.arange(4 * 5 * 6, dtype=np.int16).reshape(4, 5, 6)
    p = tmp_path / "v.tif"
    tifffile.imwrite(p, data, photometric="minisblack")
    D = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    v = read_tiff_volume(p, [0.5, 0.6, 1.2], origin=[1, 2, 3], direction=D, hu_offset=-1024)
    assert v.shape_ijk == (6, 5, 4) and v.units == "HU" and v.name == "v"
    np.testing.assert_array_equal(v.data, data - 1024.0)
    np.testing.assert_allclose(v.index_to_physical([1, 0, 0]), [1, 2.5, 3])
    a = read_tiff_volume(p, [1, 1, 1], units="1/mm")
    assert a.units == "1/mm"


def test_bad_files_are_named(tmp_path):
    with pytest.raises(ValueError, match="no such TIFF"):
        read_tiff_volume(tmp_path / "missing.tif", [1, 1, 1])
    rgb = tmp_path / "rgb.tif"
    tifffile.imwrite(rgb, np.zeros((50, 40, 3), np.uint8), photometric="rgb")
    with pytest.raises(ValueError, match=r"rgb\.tif has 3 samples per pixel"):
        read_tiff_volume(rgb, [1, 1, 1])
    flat = tmp_path / "flat.tif"
    tifffile.imwrite(flat, np.zeros((50, 40), np.uint16))
    with pytest.raises(ValueError, match=r"flat\.tif holds an array of shape"):
        read_tiff_volume(flat, [1, 1, 1])
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"not a tiff")
    with pytest.raises(ValueError, match="cannot read"):
        read_tiff_volume(junk, [1, 1, 1])
    with pytest.raises(ValueError, match="spacing"):
        read_tiff_volume(flat, [1, 1])

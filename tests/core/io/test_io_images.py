"""core.io.images: first images of a folder of camera images (not a study)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from core.io.errors import FileError
from core.io.images import camera_images, read_image


def test_read_image_npy_tiff_png_and_stacks(tmp_path):
    tifffile = pytest.importorskip("tifffile")
    cv2 = pytest.importorskip("cv2")
    img = np.arange(15, dtype=np.uint16).reshape(3, 5)  # [row, col]
    np.save(tmp_path / "a.npy", img)
    tifffile.imwrite(tmp_path / "stack.tif", np.stack([img, img + 1]))
    cv2.imwrite(str(tmp_path / "a.png"), img)
    np.testing.assert_array_equal(read_image(tmp_path / "a.npy"), img)
    np.testing.assert_array_equal(read_image(tmp_path / "stack.tif"), img)  # first frame
    np.testing.assert_array_equal(read_image(tmp_path / "a.png"), img)


@pytest.mark.parametrize("name", ["missing.png", "bad.tif", "bad.npy", "bad.png", "a.bmp"])
def test_read_image_errors_name_the_file(tmp_path, name):
    for bad in ("bad.tif", "bad.npy", "bad.png", "a.bmp"):
        (tmp_path / bad).write_bytes(b"not an image at all")
    with pytest.raises(FileError) as exc:
        read_image(tmp_path / name)
    assert str(tmp_path / name) in str(exc.value)


def test_camera_images_by_name_skip_non_fluoro(tmp_path):
    for cam in (2, 1):
        (tmp_path / f"cam{cam:02d}").mkdir()
        np.save(tmp_path / f"cam{cam:02d}" / "frame0000.npy", np.full((4, 5), cam))
        np.save(tmp_path / f"cam{cam:02d}" / "drr0000.npy", np.zeros((4, 5)))
    (tmp_path / "flatfield_cam01.npy").write_bytes(b"x")
    found = camera_images(tmp_path)
    assert [label for label, _ in found] == ["cam01: cam01/frame0000.npy",
                                            "cam02: cam02/frame0000.npy"]
    assert [read_image(p)[0, 0] for _, p in found] == [1, 2]
    assert len(camera_images(tmp_path, n_views=1)) == 1


def test_camera_images_listed_in_a_summary(tmp_path):
    frames = {"camB": ["b/0.npy", "b/1.npy"], "camA": ["a/0.npy"]}
    (tmp_path / "summary.json").write_text(json.dumps({"files": {"frames": frames}}))
    assert camera_images(tmp_path) == [("camA: a/0.npy", tmp_path / "a" / "0.npy"),
                                       ("camB: b/0.npy", tmp_path / "b" / "0.npy")]
    (tmp_path / "summary.json").write_text(json.dumps({"files": {"frames": {"camA": []}}}))
    with pytest.raises(FileError, match="no frames written"):
        camera_images(tmp_path)
    (tmp_path / "summary.json").write_text("{ broken")
    with pytest.raises(FileError, match=r"summary\.json"):
        camera_images(tmp_path)


def test_camera_images_errors_name_the_folder(tmp_path):
    with pytest.raises(FileError, match="no camera images found"):
        camera_images(tmp_path)
    with pytest.raises(FileError, match="not a folder"):
        camera_images(tmp_path / "nowhere")

import cv2
import numpy as np
import pytest
import tifffile

from core.io import (
    MultipageTiffSequence,
    TiffFolderSequence,
    TwoViewSequence,
    VideoSequence,
    open_sequence,
)
from core.io.cine_writer import write_cine


def _frames(n=5, shape=(12, 16), hi=4096, seed=0, dtype=np.uint16):
    return np.random.default_rng(seed).integers(0, hi, size=(n, *shape)).astype(dtype)


def _folder(path, frames, names=None):
    path.mkdir(parents=True, exist_ok=True)
    names = names or [f"img_{k:04d}.tif" for k in range(len(frames))]
    for f, name in zip(frames, names, strict=True):
        tifffile.imwrite(path / name, f)
    return path


def test_tiff_folder_numeric_order_and_numbers(tmp_path):
    fr = _frames(3)
    folder = _folder(tmp_path / "cam1", fr, ["x.cam1.2.tif", "x.cam1.10.tif", "x.cam1.7.TIFF"])
    seq = open_sequence(folder, bit_depth=12)
    assert isinstance(seq, TiffFolderSequence)
    np.testing.assert_array_equal(seq.frame_numbers, [2, 7, 10])  # numeric, not lexical
    np.testing.assert_array_equal(seq[0], fr[0])
    np.testing.assert_array_equal(seq[1], fr[2])
    np.testing.assert_array_equal(seq[-1], fr[1])
    assert [f.shape for f in seq] == [(12, 16)] * 3
    assert seq.shape == (3, 12, 16) and seq.bit_depth == 12 and seq.frame_rate is None
    with pytest.raises(IndexError, match=r"frame 3 out of range for .*cam1 \(3 frames\)"):
        seq[3]
    with pytest.raises(TypeError):
        seq[1.0]


def test_tiff_folder_bad_frames_are_named(tmp_path):
    fr = _frames(3)
    folder = _folder(tmp_path / "f", fr)
    tifffile.imwrite(folder / "img_0003.tif", _frames(1, shape=(12, 15))[0])
    seq = TiffFolderSequence(folder)
    msg = r"img_0003\.tif: frame of 15x12 uint16 pixels; expected 16x12 uint16"
    with pytest.raises(ValueError, match=msg):
        seq[3]
    f2 = _folder(tmp_path / "float", fr[:1].astype(np.float32))
    msg = r"img_0000\.tif: expected 8-, 12- or 16-bit unsigned frames .*got float32"
    with pytest.raises(ValueError, match=msg):
        TiffFolderSequence(f2)
    f3 = _folder(tmp_path / "signed", fr[:1].astype(np.int16))
    with pytest.raises(ValueError, match="got int16"):
        TiffFolderSequence(f3)
    rgb = tmp_path / "rgb"
    rgb.mkdir()
    tifffile.imwrite(rgb / "a1.tif", np.zeros((8, 8, 3), np.uint8), photometric="rgb")
    with pytest.raises(ValueError, match="expected single-channel grey-level frames"):
        TiffFolderSequence(rgb)
    over = _folder(tmp_path / "over", [np.full((4, 4), 5000, np.uint16)])
    msg = r"frame 0 has value 5000 above the declared 12-bit range \[0, 4095\]"
    with pytest.raises(ValueError, match=msg):
        TiffFolderSequence(over, bit_depth=12)[0]
    with pytest.raises(ValueError, match="bit_depth"):
        TiffFolderSequence(over, bit_depth=9)
    dup = _folder(tmp_path / "dup", fr[:2], ["a_1.tif", "b_1.tif"])
    with pytest.raises(ValueError, match="two frames numbered 1"):
        TiffFolderSequence(dup)
    (tmp_path / "empty").mkdir()
    with pytest.raises(ValueError, match=r"holds no \.tif"):
        TiffFolderSequence(tmp_path / "empty")


def test_multipage_tiff_is_memory_mapped(tmp_path):
    fr = _frames(6)
    p = tmp_path / "stack.tif"
    tifffile.imwrite(p, fr, photometric="minisblack")
    with open_sequence(p) as seq:
        assert isinstance(seq, MultipageTiffSequence) and seq.memory_mapped
        img = seq[4]
        assert isinstance(img.base, np.memmap) or isinstance(img, np.memmap)
        np.testing.assert_array_equal(img, fr[4])
        np.testing.assert_array_equal(seq[::2], fr[::2])


def test_multipage_tiff_compressed_and_8bit(tmp_path):
    fr = _frames(4, hi=256, dtype=np.uint8)
    p = tmp_path / "z.tiff"
    tifffile.imwrite(p, fr, compression="zlib", photometric="minisblack")
    with MultipageTiffSequence(p) as seq:
        assert not seq.memory_mapped and seq.dtype == np.uint8 and seq.bit_depth == 8
        for k in (3, 0, 2):
            np.testing.assert_array_equal(seq[k], fr[k])
    bad = tmp_path / "f.tif"
    tifffile.imwrite(bad, fr.astype(np.float32), photometric="minisblack")
    with pytest.raises(ValueError, match=r"f\.tif: expected 8-, 12- or 16-bit unsigned frames"):
        MultipageTiffSequence(bad)
    junk = tmp_path / "junk.tif"
    junk.write_bytes(b"II*\x00garbage")
    with pytest.raises(ValueError, match=r"junk\.tif: cannot read as a multipage TIFF"):
        open_sequence(junk)


def test_video_random_access(tmp_path):
    fr = _frames(7, shape=(48, 64), hi=256, dtype=np.uint8)
    p = tmp_path / "v.avi"
    w = cv2.VideoWriter(str(p), cv2.VideoWriter_fourcc(*"FFV1"), 250.0, (64, 48), isColor=False)
    for f in fr:
        w.write(f)
    w.release()
    with open_sequence(p) as seq:
        assert isinstance(seq, VideoSequence) and len(seq) == 7 and seq.frame_rate == 250.0
        for k in (5, 1, 2, 6, 0):  # lossless codec: exact frames in any order
            np.testing.assert_array_equal(seq[k], fr[k])
    yy, xx = np.mgrid[:48, :64]
    waves = [100 + 50 * np.sin(xx / 9 + k) + 30 * np.cos(yy / 7) for k in range(6)]
    smooth = np.stack(waves).astype(np.uint8)
    mp4 = tmp_path / "v.mp4"
    w = cv2.VideoWriter(str(mp4), cv2.VideoWriter_fourcc(*"mp4v"), 30.0, (64, 48), isColor=True)
    for f in smooth:
        w.write(cv2.cvtColor(f, cv2.COLOR_GRAY2BGR))
    w.release()
    with open_sequence(mp4) as seq:
        assert len(seq) == 6
        assert np.abs(seq[4].astype(int) - smooth[4]).mean() < 3  # lossy codec, right frame
        assert np.abs(seq[4].astype(int) - smooth[1]).mean() > 10
    (tmp_path / "v.xyz").write_bytes(b"?")
    with pytest.raises(ValueError, match="cannot tell the format"):
        open_sequence(tmp_path / "v.xyz")
    with pytest.raises(ValueError, match="does not exist"):
        open_sequence(tmp_path / "nope.abc")


def test_two_views_with_offset(tmp_path):
    a = _frames(10, seed=1)
    b = _frames(10, seed=2)
    pa, pb = tmp_path / "a.cine", tmp_path / "b.cine"
    write_cine(pa, a, storage="p12", frame_rate=500)
    write_cine(pb, b, storage="p12", frame_rate=500)
    with TwoViewSequence(open_sequence(pa), open_sequence(pb), offset=3) as tv:
        assert len(tv) == 7 and tv.frame_rate == 500
        for t in (0, 6, -1):
            i0, i1 = tv[t]
            k0, k1 = tv.view_frames(t)
            assert k1 == k0 + 3
            np.testing.assert_array_equal(i0, a[k0])
            np.testing.assert_array_equal(i1, b[k1])
        with pytest.raises(IndexError):
            tv.view_frames(7)
    tv = TwoViewSequence(open_sequence(pa), open_sequence(pb), offset=-2)
    assert tv.view_frames(0) == (2, 0) and len(tv) == 8
    with pytest.raises(ValueError, match="leaves no frame in common"):
        TwoViewSequence(open_sequence(pa), open_sequence(pb), offset=10)
    short = tmp_path / "short.cine"
    write_cine(short, b[:8], storage="p12", frame_rate=500)
    msg = r"mismatched frame counts: .*a\.cine has 10 frames, .*short\.cine has 8"
    with pytest.raises(ValueError, match=msg):
        TwoViewSequence(open_sequence(pa), open_sequence(short))
    assert len(TwoViewSequence(open_sequence(pa), open_sequence(short), trim=True)) == 8
    fast = tmp_path / "fast.cine"
    write_cine(fast, b, storage="p12", frame_rate=1000)
    with pytest.raises(ValueError, match="different frame rates"):
        TwoViewSequence(open_sequence(pa), open_sequence(fast))


def test_real_wrist_radiograph_folders(sample_data):
    base = sample_data / "autoscoper_wrist" / "XMA_UND"
    cams = [open_sequence(base / f"xr_data_wrist_cam0{k}") for k in (1, 2)]
    for seq in cams:
        assert seq.shape == (3, 1760, 1760) and seq.dtype == np.uint8
        np.testing.assert_array_equal(seq.frame_numbers, [2, 99, 158])
    tv = TwoViewSequence(*cams)
    img0, img1 = tv[1]
    assert img0.std() > 10 and img1.std() > 10  # real radiographs, not blank pages
    knee = [open_sequence(base / f"xr_data_left_knee_cam0{k}") for k in (1, 2)]
    np.testing.assert_array_equal(knee[1].frame_numbers, [138, 180, 272])

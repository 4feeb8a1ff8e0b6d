import struct

import numpy as np
import pytest

from core.io.cine import CineSequence, read_cine_info, unpack_10bit, unpack_12bit
from core.io.cine_writer import pack_10bit, pack_12bit, write_cine
from core.io.sequences import open_sequence

STORAGES = [("uint8", 8), ("uint16", 12), ("uint16", 16), ("p10", 10), ("p12", 12)]


def _frames(bits, n=4, shape=(6, 10), seed=0):
    return np.random.default_rng(seed).integers(0, 1 << bits, size=(n, *shape)).astype(np.uint16)


@pytest.mark.parametrize(("storage", "bits"), STORAGES)
@pytest.mark.parametrize("flip_v", [False, True])
def test_round_trip_and_header(tmp_path, storage, bits, flip_v):
    fr = _frames(bits)
    p = tmp_path / "t.cine"
    ts = np.array([-0.0021, -0.0011, 0.0, 0.00125])
    write_cine(p, fr, storage=storage, bit_depth=bits, frame_rate=800, exposure_s=250e-6,
               first_image_no=-2, trigger_time_s=1.7e9 + 0.25, timestamps=ts,
               exposures=[1e-4, 2e-4, 3e-4, 4e-4], annotation=b"note", flip_v=flip_v,
               description="walk 01 cam 1", black_level=64, white_level=4000)
    with open_sequence(p) as seq:
        assert isinstance(seq, CineSequence)
        assert len(seq) == 4 and seq.frame_shape == (6, 10) and seq.bit_depth == bits
        assert seq.dtype == (np.uint8 if storage == "uint8" else np.uint16)
        for k in range(4):
            np.testing.assert_array_equal(seq[k], fr[k])
        np.testing.assert_array_equal(seq[1:3], fr[1:3])
        np.testing.assert_array_equal(seq.frame_numbers, [-2, -1, 0, 1])
        np.testing.assert_allclose(seq.timestamps, ts, atol=1e-9)  # 32.32 fixed point
        np.testing.assert_allclose(seq.exposures, [1e-4, 2e-4, 3e-4, 4e-4], atol=1e-9)
        i = seq.info
        assert (i.frame_rate, i.exposure_s, i.first_image_no, i.storage) == (800.0, 250e-6, -2, storage)
        assert i.trigger_time_s == pytest.approx(1.7e9 + 0.25, abs=1e-6)
        assert (i.black_level, i.white_level, i.description) == (64, 4000, "walk 01 cam 1")
        assert seq.memory_mapped == (storage in ("uint8", "uint16"))
        with pytest.raises(IndexError, match=r"frame 4 out of range .*t\.cine \(4 frames\)"):
            seq[4]
    assert read_cine_info(p).image_count == 4


def test_uncompressed_frames_are_read_only_views_of_the_file(tmp_path):
    fr = _frames(12, n=3, shape=(64, 64))
    p = tmp_path / "big.cine"
    write_cine(p, fr, storage="uint16", bit_depth=12)
    seq = CineSequence(p)
    img = seq[2]
    assert np.shares_memory(img, seq._mm) and not img.flags.writeable
    np.testing.assert_array_equal(img, fr[2])
    seq.close()


def test_layout_matches_the_specification(tmp_path):
    """Byte-level facts of the public format, independent of the reader."""
    assert pack_12bit(np.array([0xABC, 0x123])) == bytes([0xAB, 0xC1, 0x23])
    assert pack_10bit(np.array([0x3FF, 0x000, 0x2AA, 0x155])) == bytes([0xFF, 0xC0, 0x0A, 0xA9, 0x55])
    raw = np.frombuffer(b"\xab\xc1\x23", np.uint8)
    np.testing.assert_array_equal(unpack_12bit(raw, (1, 2)), [[0xABC, 0x123]])
    raw = np.frombuffer(bytes([0xFF, 0xC0, 0x0A, 0xA9, 0x55]), np.uint8)
    np.testing.assert_array_equal(unpack_10bit(raw, (2, 2)), [[0x3FF, 0], [0x2AA, 0x155]])
    fr = _frames(16, n=2, shape=(3, 4))
    p = tmp_path / "s.cine"
    write_cine(p, fr, storage="uint16", frame_rate=1000, exposure_s=0.5e-3)
    b = p.read_bytes()
    assert b[:2] == b"CI" and struct.unpack_from("<H", b, 2)[0] == 44
    count, off_bmp, off_setup, off_img = struct.unpack_from("<IIII", b, 20)
    assert count == 2 and off_bmp == 44
    assert struct.unpack_from("<ii", b, off_bmp + 4) == (4, 3)  # biWidth, biHeight
    assert b[off_setup + 140 : off_setup + 142] == b"ST"
    assert struct.unpack_from("<I", b, off_setup + 768)[0] == 1000  # FrameRate
    assert struct.unpack_from("<I", b, off_setup + 1568)[0] == 500_000  # ShutterNs
    p0 = struct.unpack_from("<q", b, off_img)[0]
    ann = struct.unpack_from("<I", b, p0)[0]
    first_row = np.frombuffer(b, "<u2", count=4, offset=p0 + ann)
    np.testing.assert_array_equal(first_row, fr[0][-1])  # uncompressed rows are stored bottom-up


def test_lut(tmp_path):
    fr = _frames(10)
    p = tmp_path / "p10.cine"
    write_cine(p, fr, storage="p10")
    lut = (np.arange(1024) * 4).astype(np.uint16)
    with CineSequence(p, lut=lut) as seq:
        np.testing.assert_array_equal(seq[0], fr[0] * 4)
        assert seq.bit_depth == 12
    with pytest.raises(ValueError, match="lut: expected 1024 non-negative integers"):
        CineSequence(p, lut=np.arange(4096))


def _corrupt(tmp_path, name, data: bytes):
    p = tmp_path / name
    p.write_bytes(data)
    return p


def test_bad_files_are_named(tmp_path):
    fr = _frames(12, n=3, shape=(8, 8))
    p = tmp_path / "good.cine"
    write_cine(p, fr, storage="p12")
    good = p.read_bytes()
    with pytest.raises(ValueError, match=r"cut\.cine: truncated cine: image 2 of 3 needs bytes up to \d+"):
        CineSequence(_corrupt(tmp_path, "cut.cine", good[:-10]))
    with pytest.raises(ValueError, match="truncated or corrupt cine"):
        CineSequence(_corrupt(tmp_path, "head.cine", good[:100]))
    with pytest.raises(ValueError, match="not a Phantom cine file"):
        CineSequence(_corrupt(tmp_path, "tif.cine", b"II*\x00" + good[4:]))
    colour = bytearray(good)
    struct.pack_into("<H", colour, 4, 1)
    with pytest.raises(ValueError, match="only grey-level cines"):
        CineSequence(_corrupt(tmp_path, "jpeg.cine", bytes(colour)))
    cfa = bytearray(good)
    struct.pack_into("<I", cfa, 84 + 808, 3)
    with pytest.raises(ValueError, match=r"colour sensor \(CFA 3\)"):
        CineSequence(_corrupt(tmp_path, "cfa.cine", bytes(cfa)))
    comp = bytearray(good)
    struct.pack_into("<I", comp, 44 + 16, 2)  # BI_RLE8
    with pytest.raises(ValueError, match="unsupported pixel storage"):
        CineSequence(_corrupt(tmp_path, "rle.cine", bytes(comp)))
    small = bytearray(good)
    struct.pack_into("<i", small, 44 + 4, 7)  # width 7: image size no longer matches
    with pytest.raises(ValueError, match=r"image 0 holds 96 bytes; expected 84"):
        CineSequence(_corrupt(tmp_path, "w.cine", bytes(small)))
    with pytest.raises(ValueError, match="no such cine"):
        CineSequence(tmp_path / "missing.cine")
    with pytest.raises(ValueError, match="values outside"):
        write_cine(tmp_path / "x.cine", fr + 4096, storage="p12")
    assert not (tmp_path / "x.cine").exists()  # nothing written

"""Property-based fuzzing of the cine parser: damaged files raise FileError naming the file, nothing else."""

import itertools
import struct

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core.errors import FileError
from core.io.cine import CineSequence
from core.io.cine_writer import write_cine

TRIED = {"truncate": 0, "bytes": 0, "fields": 0}
OUTCOME = {"opened": 0, "rejected": 0}
_names = itertools.count()


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    d = tmp_path_factory.mktemp("cinefuzz")
    p = d / "good.cine"
    fr = np.random.default_rng(1).integers(0, 4096, size=(3, 4, 6)).astype(np.uint16)
    write_cine(p, fr, storage="p12", annotation=b"xy")
    p16 = d / "good16.cine"
    write_cine(p16, fr, storage="uint16", bit_depth=12)
    return d, p.read_bytes(), p16.read_bytes()


def _try(folder, data: bytes) -> bool:
    """True if the file opened (and every frame was read), False if rejected with ValueError."""
    p = folder / f"f{next(_names)}.cine"  # a new name each time: never truncate a mapped file
    p.write_bytes(data)
    try:
        seq = CineSequence(p)
    except FileError as exc:
        assert str(p) in str(exc), str(exc)
        OUTCOME["rejected"] += 1
        return False
    try:  # per-image headers are checked when each image is read
        for k in range(len(seq)):
            img = seq[k]
            assert img.shape == seq.frame_shape
    except FileError as exc:
        assert str(p) in str(exc), str(exc)
        OUTCOME["rejected"] += 1
        return False
    finally:
        seq.close()
    OUTCOME["opened"] += 1
    return True


FUZZ = settings(
    max_examples=250,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)


@FUZZ
@given(data=st.data())
def test_truncated_files(good, data):
    folder, a, b = good
    blob = (a, b)[data.draw(st.integers(0, 1))]
    cut = data.draw(st.integers(0, 1 << 30)) % len(blob)
    TRIED["truncate"] += 1
    assert not _try(folder, blob[:cut])  # every truncation is detected


@FUZZ
@given(data=st.data())
def test_random_byte_damage(good, data):
    folder, a, b = good
    blob = bytearray((a, b)[data.draw(st.integers(0, 1))])
    for _ in range(data.draw(st.integers(1, 8))):
        blob[data.draw(st.integers(0, 1 << 30)) % len(blob)] = data.draw(st.integers(0, 255))
    TRIED["bytes"] += 1
    _try(folder, bytes(blob))


# header/table fields a damaged file is most likely to get wrong (offset in file, format)
FIELDS = [(4, "<H"), (6, "<H"), (16, "<i"), (20, "<I"), (24, "<I"), (28, "<I"), (32, "<I"),
          (48, "<i"), (52, "<i"), (58, "<H"), (60, "<I"), (84 + 142, "<H"), (84 + 760, "<i"),
          (84 + 896, "<I"), (84 + 5740, "<I"), (84 + 5740 + 4, "<H")]


@FUZZ
@given(
    which=st.integers(0, 1),
    edits=st.lists(st.tuples(st.integers(0, len(FIELDS) + 2), st.integers(0, (1 << 64) - 1),
                             st.booleans()), min_size=1, max_size=3),
)
def test_damaged_header_fields(good, which, edits):
    folder, a, b = good
    blob = bytearray((a, b)[which])
    off_img = struct.unpack_from("<I", blob, 32)[0]
    p0 = struct.unpack_from("<q", blob, off_img)[0]
    fields = [*FIELDS, (off_img, "<q"), (off_img + 8, "<q"), (p0, "<I")]
    for index, raw, small in edits:
        off, fmt = fields[index]
        bits = struct.calcsize(fmt) * 8
        value = raw % (1 << 17) - 16 if small else raw % (1 << bits)  # small values hit the checks
        if fmt[-1].islower():
            value = (value + (1 << (bits - 1))) % (1 << bits) - (1 << (bits - 1))
        else:
            value %= 1 << bits
        struct.pack_into(fmt, blob, off, value)
    TRIED["fields"] += 1
    _try(folder, bytes(blob))


def test_zz_report_counts():
    """Runs after the fuzz tests of this module (alphabetical order within the file)."""
    total = sum(TRIED.values())
    print(f"cine fuzz: {TRIED} = {total} inputs; {OUTCOME}")
    assert total == 0 or OUTCOME["rejected"] > 0

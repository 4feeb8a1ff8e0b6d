"""Property-based fuzzing of the text parsers: damaged files raise FileError naming the file, nothing else."""

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core.errors import FileError
from core.geometry import make_rigid, rotvec_to_matrix
from core.io.autoscoper import read_autoscoper_cfg, read_tra, read_vie, write_tra
from core.io.xmalab import read_dlt_csv, read_points_2d, read_points_3d, write_points_2d

TRIED: dict[str, int] = {}
OUTCOME = {"parsed": 0, "rejected": 0}
_names = itertools.count()

CFG = """# trial
Version 1.1
mayaCam_csv calib/cam1.txt
mayaCam_csv calib/cam2.txt
CameraRootDir frames/cam1/
CameraRootDir frames/cam2/
VolumeFile volumes/rad.tif
VolumeFlip 0 0 0
VoxelSize 0.39625 0.39625 0.625
RenderResolution 512 512
OptimizationOffsets 0.1 0.1 0.1 0.1 0.1 0.1
"""
VIE = """RadFilters_begin
SobelFilter_begin
Scale 0.43
Blend 3
SobelFilter_end
RadFilters_end
DrrRenderer_begin
SampleDistance 0.62
RayIntensity 0.35
Cutoff 0
DrrRenderer_end
DrrFilters_begin
GaussianFilter_begin
Radius 2
GaussianFilter_end
DrrFilters_end
"""
ALPHABET = st.sampled_from([*"0123456789.,-+ e\n\t#_", "NaN", "inf", "begin", "_end", "Version", "1.1"])


@pytest.fixture(scope="module")
def samples(tmp_path_factory):
    d = tmp_path_factory.mktemp("parsers")
    rot = rotvec_to_matrix(np.random.default_rng(0).normal(size=(3, 2, 3)))
    P = make_rigid(rot, np.arange(18.0).reshape(3, 2, 3))
    P[1, 1] = np.nan
    write_tra(d / "a.tra", P)
    write_tra(d / "b.tra", P, layout="xyzypr", separator=" ")
    pts = np.random.default_rng(1).uniform(0, 200, size=(3, 2, 2, 2))
    write_points_2d(d / "p.csv", ["a", "b"], pts)
    dlt = "\n".join(",".join(str(0.1 * (i + j)) for j in range(2)) for i in range(11)) + "\n"
    p3 = "m_X , m_Y , m_Z\n1 , 2 , 3\nNaN , NaN , NaN\n"
    return d, {
        "cfg": (CFG, read_autoscoper_cfg),
        "vie": (VIE, read_vie),
        "tra_matrix": ((d / "a.tra").read_text(), read_tra),
        "tra_xyzypr": ((d / "b.tra").read_text(), read_tra),
        "dlt": (dlt, read_dlt_csv),
        "points2d": ((d / "p.csv").read_text(), read_points_2d),
        "points3d": (p3, read_points_3d),
    }


@st.composite
def mutated(draw, text: str) -> str:
    s = list(text)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(["delete", "insert", "replace", "truncate"]))
        i = draw(st.integers(0, 1 << 20)) % (len(s) + 1)
        if op == "delete" and s:
            j = min(len(s), i + draw(st.integers(1, 20)))
            del s[i:j]
        elif op == "insert":
            s[i:i] = list(draw(ALPHABET))
        elif op == "replace" and i < len(s):
            s[i] = draw(ALPHABET)
        elif op == "truncate":
            del s[i:]
    return "".join(s)


FUZZ = settings(
    max_examples=150,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow],
)
KINDS = ["cfg", "vie", "tra_matrix", "tra_xyzypr", "dlt", "points2d", "points3d"]


def _parse(folder, kind, reader, text) -> None:
    p = folder / f"f{next(_names)}.{kind.split('_')[0]}"
    p.write_text(text, encoding="utf-8")
    TRIED[kind] = TRIED.get(kind, 0) + 1
    try:
        reader(p)
    except FileError as exc:
        assert str(p) in str(exc), str(exc)
        OUTCOME["rejected"] += 1
    else:
        OUTCOME["parsed"] += 1


@pytest.mark.parametrize("kind", KINDS)
@FUZZ
@given(data=st.data())
def test_mutated_files(samples, kind, data):
    folder, table = samples
    text, reader = table[kind]
    _parse(folder, kind, reader, data.draw(mutated(text)))


@pytest.mark.parametrize("kind", KINDS)
@FUZZ
@given(text=st.text(max_size=300))
def test_arbitrary_text(samples, kind, text):
    folder, table = samples
    _parse(folder, kind + "_text", table[kind][1], text)


def test_valid_samples_parse(samples):
    folder, table = samples
    for kind, (text, reader) in table.items():
        p = folder / f"valid.{kind.split('_')[0]}"
        p.write_text(text)
        reader(p)


def test_zz_report_counts():
    total = sum(TRIED.values())
    print(f"text parser fuzz: {total} inputs {dict(sorted(TRIED.items()))}; {OUTCOME}")
    assert total == 0 or OUTCOME["rejected"] > 0

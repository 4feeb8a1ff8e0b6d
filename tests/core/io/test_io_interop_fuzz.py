"""Fuzzing of the interop readers (XMALab rigid-body CSV, ITK .tfm, JointTrack .jts, OpenSim
.mot/.trc, JCS CSV, C3D): damaged files raise FileError naming the file, nothing else."""

from __future__ import annotations

import itertools

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core.errors import FileError

_names = itertools.count()
ALPHABET = st.sampled_from([*"0123456789.,-+ e\n\t\r#_:", "NaN", "inf", "Hz", "_R11", "Frame", "endheader",
                            "NOT_OPTIMIZED", "Transform:", "Parameters:", "time"])
FUZZ = settings(max_examples=80, deadline=None, database=None,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


@pytest.fixture(scope="module")
def samples(tmp_path_factory):
    from scipy.spatial.transform import Rotation

    from core.io.jcs_csv import JCSTable, write_jcs_csv
    from core.io.jointtrack import write_jts
    from core.io.opensim import MarkerTable, MotionTable, write_mot, write_trc
    from core.io.rigid_body_csv import write_rigid_body_csv
    from core.io.slicer_tfm import write_slicer_tfm

    d = tmp_path_factory.mktemp("interop")
    P = np.tile(np.eye(4), (3, 2, 1, 1))
    P[..., :3, :3] = Rotation.random(6, random_state=1).as_matrix().reshape(3, 2, 3, 3)
    P[..., :3, 3] = np.arange(18.0).reshape(3, 2, 3)
    P[1, 1] = np.nan
    write_rigid_body_csv(d / "rb.csv", ["a", "b"], P, cutoff_hz=10)
    write_slicer_tfm(d / "t.tfm", P[0, 0])
    write_jts(d / "p.jts", P[:, 0])
    write_mot(d / "k.mot", MotionTable(("a_tx", "a_ty"), np.arange(3) / 100, np.ones((3, 2))))
    write_trc(d / "m.trc", MarkerTable(("O", "X"), P[:, :, :3, 3], 100.0))
    write_jcs_csv(d / "j.csv", JCSTable(("ankle",), np.arange(3), np.arange(3) / 100.0, np.ones((3, 1, 6)),
                                        ("jcs ankle: tibia -> talus, e1 = x, e3 = z",)))
    return d


def _readers():
    from core.io.jcs_csv import read_jcs_csv
    from core.io.jointtrack import read_jts
    from core.io.opensim import read_mot, read_trc
    from core.io.rigid_body_csv import read_rigid_body_csv
    from core.io.slicer_tfm import read_itk_tfm

    return {"rb.csv": read_rigid_body_csv, "t.tfm": read_itk_tfm, "p.jts": read_jts, "k.mot": read_mot,
            "m.trc": read_trc, "j.csv": read_jcs_csv}


KINDS = ["rb.csv", "t.tfm", "p.jts", "k.mot", "m.trc", "j.csv"]


@st.composite
def mutated(draw, text: str) -> str:
    s = list(text)
    for _ in range(draw(st.integers(1, 6))):
        op = draw(st.sampled_from(["delete", "insert", "replace", "truncate"]))
        i = draw(st.integers(0, 1 << 20)) % (len(s) + 1)
        if op == "delete" and s:
            del s[i:min(len(s), i + draw(st.integers(1, 20)))]
        elif op == "insert":
            s[i:i] = list(draw(ALPHABET))
        elif op == "replace" and i < len(s):
            s[i] = draw(ALPHABET)
        elif op == "truncate":
            del s[i:]
    return "".join(s)


def _parse(folder, kind, text) -> None:
    p = folder / f"f{next(_names)}{kind[kind.index('.'):]}"
    p.write_text(text, encoding="utf-8")
    try:
        _readers()[kind](p)
    except FileError as exc:
        assert str(p) in str(exc), str(exc)


def test_valid_samples_parse(samples):
    for kind, reader in _readers().items():
        reader(samples / kind)


@pytest.mark.parametrize("kind", KINDS)
@FUZZ
@given(data=st.data())
def test_mutated_files(samples, kind, data):
    _parse(samples, kind, data.draw(mutated((samples / kind).read_text())))


@pytest.mark.parametrize("kind", KINDS)
@FUZZ
@given(text=st.text(max_size=300))
def test_arbitrary_text(samples, kind, text):
    _parse(samples, kind, text)


def test_c3d_damaged_bytes(tmp_path):
    pytest.importorskip("ezc3d")
    from core.io.c3d import read_c3d, write_c3d

    good = tmp_path / "g.c3d"
    write_c3d(good, ["a"], np.tile(np.eye(4), (4, 1, 1, 1)), rate=100.0)
    raw = good.read_bytes()
    rng = np.random.default_rng(0)
    cases = [raw[:n] for n in (0, 10, 511, len(raw) // 2)]
    for _ in range(8):  # each read starts a child process: keep the count small
        b = bytearray(raw)
        for i in rng.integers(0, len(b), rng.integers(1, 8)):
            b[i] = int(rng.integers(0, 256))
        cases.append(bytes(b))
    for k, data in enumerate(cases):
        p = tmp_path / f"d{k}.c3d"
        p.write_bytes(data)
        try:
            read_c3d(p)
        except FileError as exc:
            assert str(p) in str(exc)


@FUZZ
@given(data=st.data())
def test_xma_mutated_project_xml(tmp_path_factory, data):
    import zipfile

    from core.io.xma_project import read_xma_project
    from tests.core.io.test_io_xma_project import make_xma

    d = tmp_path_factory.mktemp("xma")
    good = d / "good.xma"
    make_xma(good, np.zeros((2, 3)))
    with zipfile.ZipFile(good) as zf:
        members = {n: zf.read(n).decode() for n in zf.namelist()}
    name = data.draw(st.sampled_from(sorted(members)))
    members[name] = data.draw(mutated(members[name]))
    p = d / f"f{next(_names)}.xma"
    with zipfile.ZipFile(p, "w") as zf:
        for k, v in members.items():
            zf.writestr(k, v)
    try:
        prj = read_xma_project(p)
        if prj.trials and prj.trials[0].markers:
            prj.marker_points(prj.trials[0].name, prj.trials[0].markers[0].id)
    except FileError as exc:
        assert str(p) in str(exc), str(exc)
    except ValueError as exc:  # a lookup argument (trial or marker name) that the file no longer has
        assert "trial" in str(exc) or "marker" in str(exc), str(exc)

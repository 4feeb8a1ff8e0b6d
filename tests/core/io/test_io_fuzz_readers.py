"""Property-based fuzzing of every reader: damaged files raise FileError naming the file, nothing else.

Each reader gets a valid sample file, and hypothesis damages it: a truncation, flipped bytes,
a spliced-in or deleted run of bytes, or plain garbage. Whatever the reader does with it, it
either reads it or raises :class:`core.errors.FileError` (a ``ValueError``; ``StudyError`` is a
subclass) whose message contains the damaged file's path (or, for readers of a folder, the
folder's). Any other exception, or a message that does not say which file, fails the test.

The budget is small in the suite (``FUZZ_EXAMPLES`` inputs per reader, a few seconds each);
``TALUS_FUZZ_EXAMPLES=2000 pytest tests/core/io/test_io_fuzz_readers.py -s`` runs a larger
campaign. The last test prints the inputs tried and their outcome per reader.

Every read runs under an address-space cap (``RLIMIT_AS`` = current + 1.5 GiB), so a damaged
header that announces a huge image fails with an allocation error instead of exhausting the
machine.
"""

from __future__ import annotations

import contextlib
import itertools
import os
import resource
import shutil

import numpy as np
import pytest
import tifffile
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from core.errors import FileError
from core.geometry import make_rigid, rotvec_to_matrix, write_mayacam
from core.geometry.mayacam import read_mayacam
from core.io import (
    CineSequence,
    MultipageTiffSequence,
    TiffFolderSequence,
    TwoViewSequence,
    VideoSequence,
    read_autoscoper_cfg,
    read_ct,
    read_dlt_csv,
    read_mesh,
    read_points_2d,
    read_points_3d,
    read_tiff_volume,
    read_tra,
    read_vie,
    write_cine,
    write_dlt_csv,
    write_mesh,
    write_points_2d,
    write_points_3d,
    write_tra,
)
from core.io.meshes import Mesh
from core.io.vtp import read_vtp
from core.study import Study
from core.synthetic import foot_rig


def _sibling(name: str):
    """A module of this folder (the suite runs with --import-mode=importlib: no package)."""
    import importlib.util
    from pathlib import Path

    spec = importlib.util.spec_from_file_location(f"_fuzz_{name}", Path(__file__).with_name(f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


write_dicom_series = _sibling("conftest").write_dicom_series
CFG, VIE = (getattr(_sibling("test_io_parsers_fuzz"), k) for k in ("CFG", "VIE"))

FUZZ_EXAMPLES = int(os.environ.get("TALUS_FUZZ_EXAMPLES", "40"))
TRIED: dict[str, dict[str, int]] = {}
_names = itertools.count()


# ---------------------------------------------------------------------------- samples
def _frames(n=3, shape=(8, 8), seed=0):
    return np.random.default_rng(seed).integers(0, 4096, size=(n, *shape)).astype(np.uint16)


def _read_all(seq) -> None:
    with seq:
        for k in range(len(seq)):
            assert seq[k].shape == seq.frame_shape


def _tiff_folder(path):  # path: one frame of a two-frame folder
    _read_all(TiffFolderSequence(path.parent, bit_depth=12))


def _paired(path):  # path: a frame of view 0; view 1 is intact
    a = TiffFolderSequence(path.parent)
    b = TiffFolderSequence(path.parent.parent / "view1")
    with TwoViewSequence(a, b, trim=True) as pair:
        for t in range(len(pair)):
            pair[t]


def _ct(path):
    read_ct(path, voxel_size=(0.5, 0.5, 1.0))


def _dicom(path):  # path: the last slice of a three-slice series
    read_ct(path.parent)


def _study(path):  # path: study.json of a study folder
    Study.open(path.parent, check_files=False).close()


def _build(d):
    """name -> (sample file, reader(path), folder reader?)"""
    out = {}

    def new(name):
        f = d / name
        f.mkdir()
        return f

    frames = _frames()
    f = new("tiff_frames")
    for k in range(2):
        tifffile.imwrite(f / f"frame_{k:03d}.tif", frames[k])
    out["tiff_frames"] = (f / "frame_001.tif", _tiff_folder, True)
    f = new("paired")
    for view in ("view0", "view1"):
        (f / view).mkdir()
        for k in range(2):
            tifffile.imwrite(f / view / f"f{k:03d}.tif", frames[k])
    out["paired"] = (f / "view0" / "f001.tif", _paired, True)
    tifffile.imwrite(d / "stack.tif", frames, photometric="minisblack")
    out["tiff_stack"] = (d / "stack.tif", lambda p: _read_all(MultipageTiffSequence(p, bit_depth=12)), False)
    tifffile.imwrite(d / "stack_zlib.tif", frames, compression="zlib", photometric="minisblack")
    out["tiff_stack_zlib"] = (d / "stack_zlib.tif", lambda p: _read_all(MultipageTiffSequence(p)), False)
    tifffile.imwrite(d / "volume.tif", frames.astype(np.int16), photometric="minisblack")
    out["tiff_volume"] = (d / "volume.tif", lambda p: read_tiff_volume(p, (0.5, 0.5, 1.0)), False)
    write_cine(d / "p12.cine", frames, storage="p12", annotation=b"xy")
    out["cine_p12"] = (d / "p12.cine", lambda p: _read_all(CineSequence(p)), False)
    write_cine(d / "u16.cine", frames, storage="uint16", bit_depth=12)
    out["cine_uint16"] = (d / "u16.cine", lambda p: _read_all(CineSequence(p)), False)

    import cv2

    w = cv2.VideoWriter(str(d / "clip.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 10, (16, 16), False)
    for k in range(3):
        w.write(np.full((16, 16), 40 * k, np.uint8))
    w.release()
    out["video_avi"] = (d / "clip.avi", lambda p: _read_all(VideoSequence(p)), False)

    import SimpleITK as sitk

    img = sitk.GetImageFromArray(np.arange(60, dtype=np.int16).reshape(3, 4, 5) - 1000)
    img.SetSpacing((0.5, 0.6, 1.5))
    for suffix in (".nii", ".nii.gz", ".nrrd", ".mha"):
        sitk.WriteImage(img, str(d / f"ct{suffix}"))
        out[f"ct{suffix.replace('.', '_')}"] = (d / f"ct{suffix}", _ct, False)
    files = write_dicom_series(new("dicom"), np.arange(3 * 8 * 8).reshape(3, 8, 8) - 500)
    out["ct_dicom"] = (files[-1], _dicom, True)

    tri = Mesh(np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [0, 0, 10]], float),
               np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]), "tet")
    for name, binary in (("mesh.stl", True), ("ascii.stl", False), ("mesh.ply", True), ("mesh.obj", False),
                         ("mesh.vtp", True), ("ascii.vtp", False)):
        write_mesh(tri, d / name, binary=binary)
        out[name.replace(".", "_")] = (d / name, read_mesh, False)
    out["vtp_direct"] = (d / "mesh.vtp", read_vtp, False)

    (d / "trial.cfg").write_text(CFG)
    out["autoscoper_cfg"] = (d / "trial.cfg", read_autoscoper_cfg, False)
    (d / "filters.vie").write_text(VIE)
    out["autoscoper_vie"] = (d / "filters.vie", read_vie, False)
    rot = rotvec_to_matrix(np.random.default_rng(0).normal(size=(3, 2, 3)))
    write_tra(d / "poses.tra", make_rigid(rot, np.arange(18.0).reshape(3, 2, 3)))
    out["autoscoper_tra"] = (d / "poses.tra", read_tra, False)
    write_dlt_csv(d / "dlt.csv", np.random.default_rng(1).normal(size=(2, 11)))
    out["xmalab_dlt"] = (d / "dlt.csv", read_dlt_csv, False)
    pts = np.random.default_rng(2).uniform(0, 200, size=(3, 2, 2, 2))
    write_points_2d(d / "p2.csv", ["a", "b"], pts)
    out["xmalab_points2d"] = (d / "p2.csv", read_points_2d, False)
    write_points_3d(d / "p3.csv", ["a", "b"], np.random.default_rng(3).uniform(size=(3, 2, 3)))
    out["xmalab_points3d"] = (d / "p3.csv", read_points_3d, False)

    cam = foot_rig(seed=3, pixels=16)[0]
    write_mayacam(cam, d / "cam.txt", version=2)
    out["mayacam_2"] = (d / "cam.txt", read_mayacam, False)
    write_mayacam(cam, d / "cam.csv", version=1, average_focal=True)
    out["mayacam_1"] = (d / "cam.csv", read_mayacam, False)

    Study.create(d / "study", name="fuzz").close()
    out["study_manifest"] = (d / "study" / "study.json", _study, True)
    return out


@pytest.fixture(scope="module")
def samples(tmp_path_factory):
    d = tmp_path_factory.mktemp("fuzz_readers")
    table = _build(d)
    for name, (path, reader, in_folder) in table.items():  # every sample reads
        reader(path)
        table[name] = (path, reader, in_folder, path.read_bytes())
    return d, table


# ---------------------------------------------------------------------------- damage
@st.composite
def damaged(draw, blob: bytes) -> tuple[str, bytes]:
    kind = draw(st.sampled_from(["truncate", "flip", "splice", "garbage"]))
    b = bytearray(blob)
    if kind == "truncate":
        return kind, bytes(b[: draw(st.integers(0, max(len(b) - 1, 0)))])
    if kind == "flip":
        for _ in range(draw(st.integers(1, 8))):
            i = draw(st.integers(0, len(b) - 1))
            b[i] = draw(st.integers(0, 255)) if draw(st.booleans()) else b[i] ^ (1 << draw(st.integers(0, 7)))
        return kind, bytes(b)
    if kind == "splice":
        i = draw(st.integers(0, len(b)))
        j = min(len(b), i + draw(st.integers(0, 64)))
        b[i:j] = draw(st.binary(max_size=64))
        return kind, bytes(b)
    return kind, draw(st.binary(max_size=2048))


def _vm_bytes() -> int:
    with open("/proc/self/status") as fh:
        for line in fh:
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    return 0


_CAP: list[int] = []


@contextlib.contextmanager
def _memory_cap(extra: int = 3 << 29):
    """One fixed cap for the whole run (address space at the first read + ``extra``), so that
    memory a parser leaks case after case cannot grow without bound either."""
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    if not _CAP:
        _CAP.append(_vm_bytes() + 2 * extra)
    cap = max(_CAP[0], _vm_bytes() + (64 << 20))
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _try(folder, name: str, table, kind: str, data: bytes) -> None:
    sample, reader, in_folder, _ = table[name]
    case = folder / f"case{next(_names)}"
    src_root = sample.parent.parent if name == "paired" else sample.parent
    if in_folder:
        shutil.copytree(src_root, case)
        target = case / sample.relative_to(src_root)
    else:
        case.mkdir()
        target = case / sample.name
    target.write_bytes(data)  # a new file each time: never rewrite a file a reader still maps
    counts = TRIED.setdefault(name, {"tried": 0, "read": 0, "rejected": 0})
    counts["tried"] += 1
    counts[kind] = counts.get(kind, 0) + 1
    try:
        with _memory_cap():
            reader(target)
    except FileError as exc:
        counts["rejected"] += 1
        msg = str(exc)
        named = str(target) in msg or (in_folder and str(target.parent) in msg)
        assert named, f"{name}/{kind}: error does not name {target}: {msg}"
    else:
        counts["read"] += 1
    finally:
        shutil.rmtree(case, ignore_errors=True)


FUZZ = settings(
    max_examples=FUZZ_EXAMPLES,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow,
                           HealthCheck.data_too_large],
)
READERS = [
    "tiff_frames", "paired", "tiff_stack", "tiff_stack_zlib", "tiff_volume", "cine_p12", "cine_uint16",
    "video_avi", "ct_nii", "ct_nii_gz", "ct_nrrd", "ct_mha", "ct_dicom", "mesh_stl", "ascii_stl",
    "mesh_ply", "mesh_obj", "mesh_vtp", "ascii_vtp", "vtp_direct", "autoscoper_cfg", "autoscoper_vie",
    "autoscoper_tra", "xmalab_dlt", "xmalab_points2d", "xmalab_points3d", "mayacam_2", "mayacam_1",
    "study_manifest",
]


@pytest.mark.parametrize("name", READERS)
@FUZZ
@given(data=st.data())
def test_damaged_files_raise_file_error_naming_the_file(samples, name, data):
    folder, table = samples
    kind, blob = data.draw(damaged(table[name][3]))
    _try(folder, name, table, kind, blob)


def test_missing_files_are_named(samples, tmp_path):
    _, table = samples
    for name in READERS:
        sample, reader, _, _ = table[name]
        gone = tmp_path / name / sample.name  # for readers of a folder: the folder is missing
        with pytest.raises(FileError) as err:
            reader(gone)
        assert str(gone.parent) in str(err.value), (name, str(err.value))


def test_zz_report_counts():
    total = sum(c["tried"] for c in TRIED.values())
    lines = [f"{n}: {c}" for n, c in sorted(TRIED.items())]
    print(f"\nreader fuzz ({FUZZ_EXAMPLES} examples per reader): {total} inputs\n" + "\n".join(lines))
    assert all(c["tried"] > 0 for c in TRIED.values())

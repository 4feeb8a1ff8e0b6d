"""Shared fixtures of the calibration tests: a full-size rig (projections only, nothing
rendered), and one small rendered calibration session, calibrated once for the whole run (whole
and step by step)."""

import numpy as np
import pytest

from core.synthetic import foot_rig


@pytest.fixture(scope="session")
def rig():
    """The default foot rig at 1024 px (0.29 mm pixels); used for projected points only."""
    return foot_rig(seed=0, pixels=1024)


@pytest.fixture(scope="session")
def sizes(rig):
    return [(c.width, c.height) for c in rig]


@pytest.fixture
def rng():
    return np.random.default_rng(1234)


# ------------------------------------------------------------- one small session, calibrated once
# Labelling the session's beads is the expensive part of a session calibration (~20 s of CPU on a
# 2-core machine); the files that need a calibrated session share this one for the whole test run.
# Tests read these objects and never change them (the steps' edits return copies).
@pytest.fixture(scope="session")
def memory_session():
    """An in-memory session at 384 px: 10 spiral frames, the static cube, 1 grid frame per view."""
    from core.studies.calibration.memory_session import make_memory_session

    return make_memory_session(pixels=384, n_spiral=10, n_grid=1, n_flat=4, n_dark=2, seed=3)


@pytest.fixture(scope="session")
def _memory_session_one_call(memory_session):
    """:func:`~core.calibration.session.calibrate_session` of :data:`memory_session`, and the
    distortion step and beads step it made on the way (spied, not changed)."""
    from core.calibration import session as cs

    seen = {}
    beads_step = cs.beads_step

    def spy(setup, dist, **kw):
        seen["dist"], seen["beads"] = dist, beads_step(setup, dist, **kw)
        return seen["beads"]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(cs, "beads_step", spy)
        cal = cs.calibrate_session(memory_session)
    return cal, seen["dist"], seen["beads"]


@pytest.fixture(scope="session")
def memory_session_calibrated(_memory_session_one_call):
    """:func:`core.calibration.session.calibrate_session` of :data:`memory_session` (the one call)."""
    return _memory_session_one_call[0]


@pytest.fixture(scope="session")
def memory_session_steps(memory_session, _memory_session_one_call):
    """``(setup, distortion step, beads step)`` of :data:`memory_session` run one by one as the
    calibration wizard runs them. The beads step, a function of the corrected frames alone, is the
    one call's (labelling the beads twice would double the cost): test_calibration_session_steps
    checks that the step-by-step distortion step corrects the frames exactly as the one call's."""
    from core.calibration import session as cs

    setup = cs.prepare(memory_session)
    dist = cs.distortion_step(setup, cs.flatfield_step(setup))
    return setup, dist, _memory_session_one_call[2]


# --------------------------------------------- the same session as a folder, for the file-based tests
_GROUP_FOLDERS = {"dark": "dark", "flat:70": "flat_70kV", "grid": "grid", "cube": "cube", "spiral": "spiral"}


@pytest.fixture(scope="session")
def memory_session_dir(memory_session, tmp_path_factory):
    """:data:`memory_session` written as a session folder (``session.json``, one uint16 TIFF per
    frame; views ``cam1`` and ``cam2``). Its raw frames read back exactly and its manifest gives
    the same grid, objects, pixel size and lab transform, so its corrected frames are the
    in-memory session's (checked here)."""
    import json

    import tifffile

    from core.io.calibration_session import SESSION_FORMAT, read_session

    s = memory_session
    out = tmp_path_factory.mktemp("memory_session") / "session"
    names = {cam: f"cam{v + 1}" for v, cam in enumerate(s.cameras)}
    n_frames = {}
    for (cam, group), images in s.images.items():
        folder = out / names[cam] / _GROUP_FOLDERS[group]
        folder.mkdir(parents=True)
        for i, img in enumerate(images):
            assert img.dtype == np.uint16  # raw counts: the TIFF holds them exactly
            tifffile.imwrite(folder / f"{i:04d}.tif", img, photometric="minisblack")
        n_frames[_GROUP_FOLDERS[group]] = len(images)
    man = s.manifest
    manifest = {"format": SESSION_FORMAT, "version": 1, "cameras": list(names.values()),
                "bit_depth": s.bit_depth, "frame_size": list(s.frame_size),
                "groups": {"dark": "dark", "flat": {"70": "flat_70kV"}, "grid": "grid", "cube": "cube",
                           "spiral": "spiral"},
                "kv": 70.0, "n_frames": n_frames, "grid": {"kind": "hole", **man["grid"]},
                "objects": {"cube": man["static_object"], "spiral": man["object"]},
                "pixel_size_mm": man["pixel_size_mm"],
                "T_lab_from_static_object": man["T_lab_from_static_object"]}
    (out / "session.json").write_text(json.dumps(manifest, indent=1))
    disk = read_session(out)
    for (cam, group), images in s.images.items():
        for ref, img in zip(disk.frames(names[cam], group), images, strict=True):
            assert np.array_equal(disk.read(ref), img.astype(np.float32))
    return out


@pytest.fixture(scope="session")
def memory_session_dir_beads(memory_session_dir, memory_session_steps):
    """The beads step of :data:`memory_session_dir`: :data:`memory_session_steps`' (same frames,
    same set-up), with the folder's files as the frame references."""
    import dataclasses

    from core.calibration import session as cs
    from core.io.calibration_session import read_session

    disk = cs.prepare(read_session(memory_session_dir))
    mem, _, beads = memory_session_steps
    same = ("pitch_mm", "feature_mm", "px_nominal")
    assert all(getattr(disk, k) == getattr(mem, k) for k in same), [(getattr(disk, k), getattr(mem, k))
                                                                     for k in same]
    assert (disk.target.name, disk.static.name) == (mem.target.name, mem.static.name)
    assert np.array_equal(cs._manifest_T(disk.manifest), cs._manifest_T(mem.manifest))
    refs = [disk.reader.refs(c, "spiral") for c in disk.cameras]
    static_refs = [disk.reader.refs(c, "cube") for c in disk.cameras]
    assert [len(r) for r in refs] == [len(r) for r in beads.refs]
    return dataclasses.replace(beads, refs=refs, static_refs=static_refs)

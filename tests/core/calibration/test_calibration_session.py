"""calibrate_session on a rendered in-memory session: the rig and the correction against the truth,
and each step's error on bad input (file, frame, what can be done)."""

import copy
import dataclasses

import numpy as np
import pytest

from core.calibration import session as cs
from core.calibration.bundle import _failure
from core.calibration.session import SessionError, calibrate_session


@pytest.fixture
def small_session(memory_session):
    """The 384-px session of conftest, shared with the other calibration tests (never changed)."""
    return memory_session


@pytest.fixture
def calibrated(memory_session_calibrated):
    return memory_session_calibrated


def _copy(s, **images):
    out = copy.copy(s)
    out.images = dict(s.images)
    out.manifest = copy.deepcopy(s.manifest)
    for k, v in images.items():
        cam, group = k.split("__")
        if v is None:
            out.images.pop((cam, group.replace("_", ":")), None)
        else:
            out.images[(cam, group.replace("_", ":"))] = v
    return out


def test_rig_and_correction_against_truth(small_session, calibrated):
    cal, truth = calibrated, small_session.truth
    for c, t in zip(cal.rig, truth["rig"], strict=True):
        assert c.name == t.name
        assert abs(c.fx / t.fx - 1) < 2e-3  # 384 px: 0.78 mm pixels
        assert np.linalg.norm(c.source - t.source) < 3.0
    assert cal.bundle.rms_px < 0.15
    # the pipeline undoes the distortion: ideal projections of the cube's beads land where the
    # estimated rig puts them, and the flatfield gives ~1 in an empty frame
    for v, (cam, model) in enumerate(zip(truth["rig"], truth["imaging"], strict=True)):
        flat = small_session.images[(cam.name, "flat:70")][0]
        out = cal.pipelines[v](flat)
        h, w = out.shape
        centre = out[h // 2 - 20:h // 2 + 20, w // 2 - 20:w // 2 + 20]
        assert abs(float(np.median(centre)) - 1.0) < 0.05
        d = model.distortion
        q = np.stack(np.meshgrid(np.linspace(60, 320, 7), np.linspace(60, 320, 7)), -1).reshape(-1, 2)
        grid = cal.cameras[v].grid
        # correction = similarity of the truth (absorbed by the camera): fit it and look at the rest
        p = grid.model.inverse(d.forward(q))
        A = np.column_stack([q[:, 0] + 1j * q[:, 1], np.ones(len(q))])
        coef = np.linalg.lstsq(A, p[:, 0] + 1j * p[:, 1], rcond=None)[0]
        rest = np.abs(A @ coef - (p[:, 0] + 1j * p[:, 1]))
        assert rest.max() < 0.3
        assert abs(abs(coef[0]) - 1) < 2e-3  # unit scale at the centre
    rep = cal.report
    assert rep["n_frames_labelled"] >= 9
    assert rep["bundle"]["rms_px"] == pytest.approx(cal.bundle.rms_px)
    assert {"rig", "cameras", "frames", "error_volume", "seconds"} <= set(rep)
    assert rep["rig"][0]["std"]["source_mm"][0] > 0


def test_report_files(calibrated, tmp_path):
    from core.calibration.report import write_report

    paths = write_report(calibrated, tmp_path / "rep")
    for p in paths.values():
        assert p.is_file() and p.stat().st_size > 1000
    import json

    rep = json.loads(paths["report"].read_text())
    assert rep["figures"]["grid_residuals"] == "grid_residuals.png"
    assert "_error_volume_points" not in rep


def test_missing_view(small_session):
    s = _copy(small_session, cam02__spiral=None)
    with pytest.raises(SessionError, match=r"camera cam02, 'spiral' frames: missing") as e:
        calibrate_session(s)
    assert e.value.step == "session" and "record" in e.value.hint


def test_frames_of_different_sizes(small_session):
    grid = list(small_session.images[("cam01", "grid")])
    grid[0] = grid[0][:-8]
    s = _copy(small_session, cam01__grid=grid)
    with pytest.raises(SessionError, match=r"cam01/grid/0000.tif \(frame 0\): frame of 384x376 pixels") as e:
        calibrate_session(s)
    assert e.value.step == "distortion"


def test_grid_frame_without_grid(small_session):
    grid = [small_session.images[("cam02", "flat:70")][0]]
    s = _copy(small_session, cam02__grid=grid)
    where = r"cam02/grid/0000.tif \(grid frame 0 of camera cam02\): no distortion grid"
    with pytest.raises(SessionError, match=where):
        calibrate_session(s)


def test_too_few_labelled_frames(small_session, memory_session_steps, monkeypatch):
    # a session of 3 object frames: the first 3 of this session's, whose beads are labelled already
    # (conftest; labelling them again took 12 s of CPU)
    b = memory_session_steps[2]
    three = dataclasses.replace(b, frames=b.frames[:3], detections=b.detections[:3],
                                refs=[r[:3] for r in b.refs])
    monkeypatch.setattr(cs, "beads_step", lambda setup, dist, **kw: three)
    with pytest.raises(SessionError, match=r"beads: spiral33 frames: only \d of 3 frames") as e:
        calibrate_session(small_session)
    assert "record more frames" in e.value.hint


def test_bundle_not_converging(small_session, memory_session_steps, monkeypatch):
    # the beads of this session are labelled already (conftest): the bundle adjustment is what fails
    beads = memory_session_steps[2]
    monkeypatch.setattr(cs, "beads_step", lambda setup, dist, **kw: beads)
    monkeypatch.setattr(cs, "bundle_adjust", lambda frames, sizes, **kw: _failure(
        "the optimizer did not converge (max evaluations)", len(sizes), len(frames)))
    with pytest.raises(SessionError, match=r"bundle: \d+ labelled frames \(spiral33 \+ cube15\): the bundle "
                       r"adjustment did not converge") as e:
        calibrate_session(small_session)
    assert "sid_mm" in e.value.hint


def test_cancel(small_session):
    with pytest.raises(cs.CalibrationCancelled):
        calibrate_session(small_session, cancel=lambda: True)


# ---------------------------------------------------------------------------- saved into a study
@pytest.fixture
def study(tmp_path, small_session):
    import tifffile

    from core.geometry.mayacam import write_mayacam
    from core.study import Study

    st = Study.create(tmp_path / "study")
    cams = []
    for cam in small_session.truth["rig"]:
        p = tmp_path / "rig" / f"{cam.name}.txt"
        p.parent.mkdir(exist_ok=True)
        write_mayacam(cam, p)
        cams.append(p)
        folder = tmp_path / "raw" / cam.name
        folder.mkdir(parents=True)
        for k, img in enumerate(small_session.images[(cam.name, "spiral")][:2]):
            tifffile.imwrite(folder / f"f{k:03d}.tif", img)
    st.add_calibration("rig", cams, pixel_size_mm=small_session.truth["rig"][0].pixel_size)
    st.add_trial("walk", [tmp_path / "raw" / c.name for c in small_session.truth["rig"]],
                 calibration="rig", bit_depth=12)
    yield st
    st.close()


def test_saved_versions_and_trial_correction(study, calibrated):
    from core.study.calibrations import calibration_versions, save_session_calibration, trial_correction
    from core.tracking.from_study import frame_reader

    s1 = save_session_calibration(study, calibrated, trials="all")
    assert s1.name == "session.v1" and s1.trials == ("walk",)
    assert (s1.folder / "report" / "report.json").is_file()
    trial = study.trial("walk")
    assert trial.calibration == "session.v1"
    for c, e in zip(trial.rig(), calibrated.rig, strict=True):
        assert np.allclose(c.P, e.P, rtol=1e-12, atol=1e-9)
    raw = trial.frames(1)
    pipes = trial_correction(study, "walk")
    for v in range(2):
        assert np.array_equal(pipes[v](raw[v]), calibrated.pipelines[v](raw[v]))
    read, how = frame_reader(study, trial)
    assert how == "saved with calibration session.v1"
    assert np.array_equal(read(1)[0], calibrated.pipelines[0](raw[0]))
    s2 = save_session_calibration(study, calibrated, report=False)  # the series' trials move on
    assert s2.name == "session.v2" and study.trial("walk").calibration == "session.v2"
    assert s1.folder.is_dir() and "session.v1" in study.calibrations
    assert [v["name"] for v in calibration_versions(study)] == ["session.v1", "session.v2"]


def test_failed_save_leaves_the_study_unchanged(study, calibrated, monkeypatch):
    import core.calibration.report as report
    from core.study.calibrations import save_session_calibration

    before = (study.folder / "study.json").read_bytes()

    def boom(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(report, "write_report", boom)
    with pytest.raises(OSError, match="disk full"):
        save_session_calibration(study, calibrated, trials="all")
    assert (study.folder / "study.json").read_bytes() == before
    assert list((study.folder / "calibrations" / "session").iterdir()) == []
    assert study.trial("walk").calibration == "rig"

"""An Autoscoper project opened as a study: the wrist sample described by a version 1.2 .cfg
(Windows line endings, as the sample README lists its lines) and a .tra of radius and ulna."""

from __future__ import annotations

import numpy as np
import pytest

from core.errors import FileError


def wrist_cfg(folder, data, *, crlf=True, version="1.2") -> str:
    lines = [
        f"Version {version}",
        f"mayaCam_csv {data / 'Calibration' / 'xr_calib_wrist_cam01.txt'}",
        f"mayaCam_csv {data / 'Calibration' / 'xr_calib_wrist_cam02.txt'}",
        f"CameraRootDir {data / 'XMA_UND' / 'xr_data_wrist_cam01'}",
        f"CameraRootDir {data / 'XMA_UND' / 'xr_data_wrist_cam02'}",
    ]
    for stem in ("rad", "uln"):
        lines += [f"VolumeFile {data / 'Models' / f'{stem}_dcm_cropped.tif'}", "VolumeFlip 0 0 0",
                  "VoxelSize 0.39625 0.39625 0.625"]
    lines += ["RenderResolution 512 512", "OptimizationOffsets 0.1 0.1 0.1 0.1 0.1 0.1"]
    p = folder / "wrist.cfg"
    p.write_bytes(("\r\n" if crlf else "\n").join(lines).encode() + b"\r\n")
    return p


@pytest.fixture(scope="module")
def wrist_project(tmp_path_factory, sample_data):
    data = sample_data / "autoscoper_wrist"
    if not data.is_dir():
        pytest.skip(reason=f"wrist sample not found at {data}")
    from core.io.autoscoper import write_tra
    from core.io.autoscoper_pose import tra_from_lab_from_bone
    from core.samples import load_wrist_sample
    from core.studies.io.autoscoper_wrist import BONES, wrist_tra_poses

    d = tmp_path_factory.mktemp("wrist_project")
    cfg = wrist_cfg(d, data)
    sample = load_wrist_sample(data)
    talus = wrist_tra_poses()
    tra = np.full((3, 2, 4, 4), np.nan)  # frames 0002, 0099, 0158: a pose at 0099
    for b, bone in enumerate(BONES):
        tra[1, b] = tra_from_lab_from_bone(talus[b], sample.volumes[bone])
    write_tra(d / "wrist.tra", tra)
    return d, cfg, talus


def test_wrist_cfg_opens_as_a_study_with_its_poses(wrist_project):
    from core.study import Study
    from core.study.import_project import import_project

    d, cfg, talus = wrist_project
    with import_project(cfg, d / "study", tra=d / "wrist.tra") as s:
        assert s.bones == ("rad_dcm_cropped", "uln_dcm_cropped")
        assert s.settings["imported_from"]["version"] == "1.2"
    with Study.open(d / "study") as s:
        tr = s.trial("trial")
        assert tr.n_frames == 3
        for b, bone in enumerate(s.bones):
            P = tr.poses(bone)
            assert np.isnan(P[[0, 2]]).all()
            np.testing.assert_allclose(P[1], talus[b], atol=1e-6)
        vol = s.bone_volume("rad_dcm_cropped")
        np.testing.assert_allclose(vol.spacing, [0.39625, 0.39625, 0.625])
        assert vol.data.min() == -1024
        # the study references the original files
        assert all(not str(p).startswith(str(d)) for p in tr.view_paths)


def test_bad_project_files_name_the_file(tmp_path):
    from core.study.import_project import import_project

    p = tmp_path / "bad.cfg"
    p.write_text("Version 1.2\nmayaCam_csv\n")
    with pytest.raises(FileError, match=r"bad\.cfg"):
        import_project(p, tmp_path / "s")
    with pytest.raises(ValueError, match="expected an Autoscoper"):
        import_project(tmp_path / "x.zip", tmp_path / "s")


@pytest.fixture(scope="module")
def wrist_study(wrist_project):
    from core.study.import_project import import_project

    d, cfg, talus = wrist_project
    out = d / "study_export"
    import_project(cfg, out, tra=d / "wrist.tra").close()
    return out, talus


@pytest.mark.parametrize("fmt", ["tra", "xromm-csv", "tfm", "jts", "c3d", "mot", "trc", "jcs"])
def test_export_formats_read_back(wrist_study, fmt, tmp_path):
    from core.study import Study
    from core.study.export_trial import export_trial

    folder, talus = wrist_study
    if fmt == "c3d":
        pytest.importorskip("ezc3d")
    out = tmp_path / ("out" if fmt in ("tfm", "jts") else f"out.{fmt}")
    with Study.open(folder) as s:
        paths = export_trial(s, "trial", fmt, out, rate=50.0)
        bones = s.bones
        if fmt == "tra":
            from core.io.autoscoper_pose import lab_from_bone_from_tra
            from core.io.autoscoper_tra import read_tra

            T = read_tra(out, n_volumes=2)
            for b, bone in enumerate(bones):
                np.testing.assert_allclose(lab_from_bone_from_tra(T[1, b], s.bone_volume(bone)), talus[b],
                                           atol=1e-6)
            assert np.isnan(T[0]).all()
            return
        rig = s.trial("trial").rig()
    if fmt == "xromm-csv":
        from core.io.rigid_body_csv import read_rigid_body_csv

        r = read_rigid_body_csv(out)
        assert r.bodies == bones and list(r.frames) == [1, 2, 3]
        got = r.poses[1]
    elif fmt == "tfm":
        from core.io.slicer_tfm import read_slicer_tfm

        assert [p.name for p in paths] == [f"{b}.tfm" for b in bones]
        got = np.stack([read_slicer_tfm(p) for p in paths])
    elif fmt == "jts":
        from core.io.jointtrack import jts_to_lab, read_jts

        got = np.stack([jts_to_lab(read_jts(p)[1], rig[0]) for p in paths])
    elif fmt == "c3d":
        from core.io.c3d import read_c3d

        r = read_c3d(out)
        assert r.bones == bones and r.rate == 50.0
        got = r.poses[1]
    elif fmt == "mot":
        from core.io.opensim import kinematics_to_poses, read_mot

        got = kinematics_to_poses(read_mot(out), bones)[1]
    elif fmt == "trc":
        from core.io.opensim import read_trc

        r = read_trc(out)
        assert len(r.names) == 8 and r.rate == 50.0
        np.testing.assert_allclose(r.xyz[1, 0], talus[0][:3, 3], atol=1e-6)
        np.testing.assert_allclose(r.xyz[1, 5], (talus[1] @ [10, 0, 0, 1])[:3], atol=1e-6)
        return
    else:
        from core.io.jcs_csv import read_jcs_csv

        r = read_jcs_csv(out)
        assert len(r.joints) == 1 and np.isfinite(r.values[1]).all() and np.isnan(r.values[0]).all()
        return
    np.testing.assert_allclose(got, talus, atol=1e-5)


def test_talus_track_runs_on_the_imported_wrist_study(wrist_project, tmp_path, capsys, monkeypatch):
    """The 1.2 .cfg study tracks with the command a user runs: the radius from its .tra pose in
    frame 0099 to frame 0158, at an eighth of the resolution and without the first frame's
    verifying restarts (the pipeline, not its accuracy: the restarts have their own tests)."""
    import dataclasses
    import json

    import core.tracking.trial as trial_module
    from app.cli import main
    from core.study import Study
    from core.study.import_project import import_project

    @dataclasses.dataclass(frozen=True)
    class NoRestarts(trial_module.TrackingOptions):
        verify_restarts: int = 0

    monkeypatch.setattr(trial_module, "TrackingOptions", NoRestarts)  # what talus track builds
    d, cfg, talus = wrist_project
    import_project(cfg, tmp_path / "study", tra=d / "wrist.tra").close()
    rc = main(["track", str(tmp_path / "study"), "--trial", "trial", "--bones", "rad_dcm_cropped",
               "--frames", "2:3", "--scale", "8", "--search", "newton", "--no-confidence", "--quiet"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert json.loads(out)["summary"]["results"] == 1
    with Study.open(tmp_path / "study") as s:
        P = s.trial("trial").poses("rad_dcm_cropped")
        assert np.isfinite(P[2]).all() and np.isnan(P[0]).all()  # frame 0158 tracked, 0002 left
        np.testing.assert_allclose(P[1], talus[0], atol=1e-6)  # the imported start stays
        assert [f["frame"] for f in s.read_report("tracking", "trial")["frames_done"]] == [2]

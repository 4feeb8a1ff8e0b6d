import numpy as np
import pytest

from core.geometry import make_rigid, rotvec_to_matrix
from core.study import Study, StudyError, read_journal


def _pose(k: int) -> np.ndarray:
    return make_rigid(rotvec_to_matrix([0.01 * k, -0.02, 0.3]), [k + 0.125, -2.0 * k, 1e-9 * k])


@pytest.fixture
def study(tmp_path, rig_files, views):
    st = Study.create(tmp_path / "st")
    st.add_calibration("day1", rig_files)
    vol = tmp_path / "talus.tif"
    vol.write_bytes(b"placeholder")
    st.add_volume("talus_ct", vol, voxel_size_mm=[0.5, 0.5, 0.5])
    st.add_bone("talus", volume="talus_ct")
    st.add_bone("calcaneus", volume="talus_ct")
    st.add_trial("walk01", views[0], calibration="day1", bones=["talus", "calcaneus"])
    yield st
    st.close()


def test_poses_round_trip_exactly(study):
    tr = study.trial("walk01")
    for k in (0, 2, 5):
        tr.record_pose("talus", k, _pose(k), score=0.5 + k / 10)
    tr.record_pose("calcaneus", 1, _pose(9))
    P = tr.poses("talus")
    assert P.shape == (6, 4, 4)
    for k in (0, 2, 5):
        np.testing.assert_array_equal(P[k], _pose(k))  # repr round trip: bit-exact
    assert np.isnan(P[[1, 3, 4]]).all()
    np.testing.assert_array_equal(tr.scores("talus")[[0, 2, 5]], [0.5, 0.7, 1.0])
    assert np.isnan(tr.scores("calcaneus")[1])  # no score given
    assert tr.results("talus").tracked_frames == (0, 2, 5)


def test_retrack_and_clear(study):
    tr = study.trial("walk01")
    tr.record_pose("talus", 3, _pose(3), score=0.1)
    tr.record_pose("talus", 3, _pose(4), score=0.9)  # re-tracked: the later record wins
    np.testing.assert_array_equal(tr.poses("talus")[3], _pose(4))
    tr.clear_pose("talus", 3)
    assert np.isnan(tr.poses("talus")[3]).all()
    path = study.folder / "results" / "walk01" / "poses" / "talus.jsonl"
    assert read_journal(path).n_lines == 3
    tr.compact("talus")
    assert read_journal(path).n_lines == 1  # one line per frame (the cleared one)


def test_bad_records_are_refused(study):
    tr = study.trial("walk01")
    with pytest.raises(ValueError, match=r"frame: expected an integer in \[0, 6\)"):
        tr.record_pose("talus", 6, _pose(0))
    with pytest.raises(ValueError, match=r"pose\[:3, :3\]: expected an orthonormal"):
        tr.record_pose("talus", 0, np.diag([2.0, 1, 1, 1]))
    with pytest.raises(ValueError, match="score"):
        tr.record_pose("talus", 0, _pose(0), score=float("inf"))
    with pytest.raises(StudyError, match="has no bone 'tibia'"):
        tr.record_pose("tibia", 0, _pose(0))
    assert tr.results("talus").n_lines == 0


def test_torn_tail_is_dropped_and_repaired(study):
    tr = study.trial("walk01")
    tr.record_pose("talus", 0, _pose(0))
    tr.record_pose("talus", 1, _pose(1))
    path = study.folder / "results" / "walk01" / "poses" / "talus.jsonl"
    good = path.read_bytes()
    line = good.splitlines(keepends=True)[1]
    path.write_bytes(good + line[: len(line) // 2])  # a crash in the middle of the next append
    state = read_journal(path)
    assert state.torn_bytes == len(line) // 2 and state.tracked_frames == (0, 1)
    study.close()
    with Study.open(study.folder, mode="w") as st:  # the writer cuts the torn tail before appending
        st.trial("walk01").record_pose("talus", 2, _pose(2))
        assert st.trial("walk01").results("talus").tracked_frames == (0, 1, 2)
        assert read_journal(path).torn_bytes == 0


def test_corruption_in_the_middle_is_an_error(study):
    tr = study.trial("walk01")
    for k in range(3):
        tr.record_pose("talus", k, _pose(k))
    path = study.folder / "results" / "walk01" / "poses" / "talus.jsonl"
    data = bytearray(path.read_bytes())
    data[10] ^= 0x01  # flip one bit of the first record
    path.write_bytes(bytes(data))
    with pytest.raises(StudyError, match=r"talus\.jsonl: line 1: damaged record .* corrupt"):
        tr.poses("talus")


def test_reports(study):
    p = study.write_report("calibration", "day1", {"rms_px": 0.21, "cameras": 2, "worst": None})
    assert p.parent.name == "calibration"
    assert study.read_report("calibration", "day1")["rms_px"] == 0.21
    assert study.report_names("calibration") == ("day1",)
    with pytest.raises(ValueError, match="strict JSON"):
        study.write_report("calibration", "bad", {"rms_px": float("nan")})
    with pytest.raises(StudyError, match="no 'calibration' report named 'x'"):
        study.read_report("calibration", "x")


def test_export_tra(study, tmp_path):
    from core.io.autoscoper import read_tra

    tr = study.trial("walk01")
    tr.record_pose("talus", 1, _pose(1))
    tr.record_pose("calcaneus", 1, _pose(2))
    tr.record_pose("calcaneus", 3, _pose(3))
    out = tmp_path / "walk01.tra"
    tr.export_tra(out)
    P = read_tra(out, n_volumes=2)
    assert P.shape == (6, 2, 4, 4)
    np.testing.assert_allclose(P[1, 0], _pose(1), atol=1e-12)
    np.testing.assert_allclose(P[3, 1], _pose(3), atol=1e-12)
    assert np.isnan(P[3, 0]).all() and np.isnan(P[0]).all()

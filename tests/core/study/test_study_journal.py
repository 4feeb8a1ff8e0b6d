"""The pose journal's review state (version-2 records), its compatibility with version-1
journals, compaction, and the salvage of damaged journals (``Study.repair``)."""

import json
import zlib

import numpy as np
import pytest

from core.geometry import make_rigid, rotvec_to_matrix
from core.study import Study, StudyError, read_journal, salvage_journal
from core.study.results import append_pose, compact_journal


def _pose(k: int) -> np.ndarray:
    return make_rigid(rotvec_to_matrix([0.01 * k, -0.02, 0.3]), [k + 0.125, -2.0 * k, 1e-9 * k])


def _v1_line(frame, pose, score) -> bytes:
    text = json.dumps({"frame": frame, "pose": [float(x) for x in pose.ravel()], "score": score,
                       "time": "2025-01-01T00:00:00.000+00:00"}, separators=(",", ":"))
    return f"{text}\t{zlib.crc32(text.encode()):08x}\n".encode()


TRACKED = {"flags": ["score drop (0.400 < 0.85 x recent median 0.900)"], "converged": False, "retried": True,
           "evaluations": 412, "time_s": 0.25, "confidence": {"method": "curvature", "sigma": [0.1, None]},
           "timing": {"render_s": 0.1}, "notes": []}


def test_review_state_round_trips_and_keyframes_survive_tracking(tmp_path):
    p = tmp_path / "talus.jsonl"
    append_pose(p, 0, _pose(0))                                    # hand-placed start
    append_pose(p, 0, _pose(1), score=0.9, tracking={"flags": []})  # tracked from it
    append_pose(p, 1, _pose(2), score=0.4, tracking=TRACKED)       # flagged
    append_pose(p, 2, _pose(3), score=0.8, tracking={"flags": []})
    append_pose(p, 2, _pose(4))                                    # fixed by hand afterwards
    append_pose(p, 3, _pose(5))                                    # a keyframe not yet tracked
    append_pose(p, 3, None)                                        # ... cleared
    s = read_journal(p)
    assert s.records[1].tracking == TRACKED and s.records[1].kind == "tracked" and s.records[1].score == 0.4
    np.testing.assert_array_equal(s.records[1].pose, _pose(2))
    assert {f: r.kind for f, r in s.keyframes.items()} == {0: "hand", 2: "hand"}
    np.testing.assert_array_equal(s.keyframes[0].pose, _pose(0))   # not replaced by the tracked pose
    assert {f: r.kind for f, r in s.done.items()} == {0: "tracked", 1: "tracked", 2: "hand"}
    assert s.tracked_frames == (0, 1, 2)
    n = s.n_lines
    compact_journal(p)
    c = read_journal(p)
    assert c.n_lines < n
    for attr in ("records", "keyframes", "done"):
        a, b = getattr(s, attr), getattr(c, attr)
        assert a.keys() == b.keys(), attr
        for f in a:
            assert a[f].kind == b[f].kind and a[f].tracking == b[f].tracking, (attr, f)
            if a[f].pose is not None:
                np.testing.assert_array_equal(a[f].pose, b[f].pose)
    with pytest.raises(ValueError, match="tracking: a tracking result needs a pose"):
        append_pose(p, 4, None, tracking={"flags": []})
    with pytest.raises(ValueError, match="tracking: expected strict JSON"):
        append_pose(p, 4, _pose(0), tracking={"x": float("nan")})


def test_version_1_journals_read_as_legacy_poses(tmp_path):
    p = tmp_path / "talus.jsonl"
    p.write_bytes(_v1_line(0, _pose(0), 0.5) + _v1_line(1, _pose(1), None))
    append_pose(p, 2, _pose(2), score=0.7, tracking={"flags": []})  # a new record after old ones
    s = read_journal(p)
    assert [s.records[f].kind for f in (0, 1, 2)] == ["legacy", "legacy", "tracked"]
    assert s.records[0].version == 1 and s.records[0].score == 0.5 and np.isnan(s.records[1].score)
    assert sorted(s.done) == [0, 1, 2] and sorted(s.keyframes) == [0, 1]  # as version 1 resumed
    compact_journal(p)
    assert p.read_bytes().startswith(_v1_line(0, _pose(0), 0.5)[:40])  # legacy lines stay version 1
    assert read_journal(p).records[1].kind == "legacy"


def test_a_newer_record_version_is_refused_by_name(tmp_path):
    p = tmp_path / "talus.jsonl"
    text = json.dumps({"v": 3, "frame": 0, "pose": None, "score": None, "time": ""}, separators=(",", ":"))
    p.write_bytes(f"{text}\t{zlib.crc32(text.encode()):08x}\n".encode())
    with pytest.raises(StudyError, match=r"talus\.jsonl: line 1: record version 3 is newer"):
        read_journal(p)
    with pytest.raises(StudyError, match="newer"):
        salvage_journal(p)


def _damage(path, line_no: int, offset: int = 40) -> None:
    lines = path.read_bytes().split(b"\n")
    b = bytearray(lines[line_no - 1])
    b[offset] ^= 0x01
    lines[line_no - 1] = bytes(b)
    path.write_bytes(b"\n".join(lines))


def test_salvage_keeps_every_intact_record_and_reports_the_rest(tmp_path):
    p = tmp_path / "talus.jsonl"
    for k in range(5):
        append_pose(p, k, _pose(k), score=0.5, tracking={"flags": [], "evaluations": k})
    original_lines = p.read_bytes().split(b"\n")
    _damage(p, 2)
    _damage(p, 4, offset=30)
    p.write_bytes(p.read_bytes() + b'{"v":2,"frame":9,"po')  # and a torn tail
    damaged = p.read_bytes()
    with pytest.raises(StudyError, match=r"line 2: damaged record \(checksum mismatch\).*talus study repair"):
        read_journal(p)
    dry = salvage_journal(p, dry_run=True)
    assert p.read_bytes() == damaged and not dry["changed"] and dry["backup"] is None
    rep = salvage_journal(p)
    assert rep["changed"] and rep["kept"] == 3 and rep["lines"] == 6
    assert [(d["line"], d["reason"]) for d in rep["dropped"]] == [
        (2, "checksum mismatch"), (4, "checksum mismatch"),
        (6, "torn last record (no newline: an interrupted write)")]
    assert [d.get("frame") for d in rep["dropped"]] == [1, 3, 9] and rep["frames_lost"] == [1, 3, 9]
    from pathlib import Path

    assert Path(rep["backup"]).read_bytes() == damaged  # the original, set aside
    assert p.read_bytes() == b"\n".join(original_lines[i] for i in (0, 2, 4)) + b"\n"  # intact lines verbatim
    s = read_journal(p)
    assert sorted(s.records) == [0, 2, 4] and s.records[4].tracking == {"flags": [], "evaluations": 4}
    again = salvage_journal(p)
    assert not again["changed"] and again["dropped"] == [] and again["kept"] == 3
    json.dumps(rep)  # JSON-ready


def test_study_repair_over_every_journal(tmp_path, rig_files, views):
    st = Study.create(tmp_path / "st")
    st.add_calibration("day1", rig_files)
    vol = tmp_path / "talus.tif"
    vol.write_bytes(b"placeholder")
    st.add_volume("ct", vol, voxel_size_mm=[0.5, 0.5, 0.5])
    st.add_bone("talus", volume="ct")
    st.add_bone("calcaneus", volume="ct")
    st.add_trial("walk01", views[0], calibration="day1", bones=["talus", "calcaneus"])
    tr = st.trial("walk01")
    for k in range(3):
        tr.record_pose("talus", k, _pose(k), score=0.5, tracking={"flags": []})
        tr.record_pose("calcaneus", k, _pose(k))
    st.close()
    path = st.folder / "results" / "walk01" / "poses" / "talus.jsonl"
    _damage(path, 1)
    with Study.open(st.folder) as ro:
        with pytest.raises(StudyError, match="talus study repair"):
            ro.trial("walk01").poses("talus")
        dry = ro.repair(dry_run=True)
        assert dry["damaged"] == 1 and dry["dropped_lines"] == 1
        with pytest.raises(StudyError, match="read-only"):
            ro.repair()
    with Study.open(st.folder, mode="w") as rw:
        rep = rw.repair()
        assert rep["damaged"] == 1 and {(j["trial"], j["bone"]) for j in rep["journals"]} == {
            ("walk01", "talus"), ("walk01", "calcaneus")}
        assert rw.trial("walk01").results("talus").tracked_frames == (1, 2)
        assert rw.trial("walk01").results("calcaneus").tracked_frames == (0, 1, 2)
        assert rw.repair()["damaged"] == 0
        rw.trial("walk01").record_pose("talus", 0, _pose(0))  # the journal takes appends again

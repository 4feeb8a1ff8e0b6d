import copy
import json

import numpy as np
import pytest

from core.io import atomic
from core.study import SCHEMA_VERSION, Study, StudyError, validate_manifest
from core.study.manifest import new_manifest


def _study(tmp_path, rig_files, views):
    st = Study.create(tmp_path / "st", name="subject07")
    st.add_calibration("day1", rig_files)
    st.add_trial("walk01", views[0], calibration="day1", bit_depth=12)
    return st


def test_create_edit_reopen(tmp_path, rig_files, views):
    with _study(tmp_path, rig_files, views) as st:
        st.update_settings(metric="gc", generations=20)
        assert st.mode == "w" and st.trials == ("walk01",)
    assert st.mode == "closed"
    with Study.open(tmp_path / "st") as ro:
        m = ro.manifest
        assert m["schema_version"] == SCHEMA_VERSION and m["name"] == "subject07"
        # references, not copies; stored relative to the study when outside it -> absolute
        assert m["calibrations"]["day1"]["cameras"][0] == str(rig_files[0])
        assert ro.settings == {"metric": "gc", "generations": 20}
        rig = ro.rig("day1")
        assert len(rig) == 2 and rig[0].width == 32
        tr = ro.trial("walk01")
        assert tr.n_frames == 6 and tr.view_paths == tuple(views[0])
        a, b = tr.frames(2)
        np.testing.assert_array_equal(a, views[1][0][2])
        np.testing.assert_array_equal(b, views[1][1][2])
        with pytest.raises(StudyError, match="read-only"):
            ro.update_settings(x=1)


def test_paths_inside_the_study_are_relative(tmp_path, rig_files):
    st = Study.create(tmp_path)
    st.add_calibration("c", rig_files)
    assert st.manifest["calibrations"]["c"]["cameras"] == ["calib/cam1.txt", "calib/cam2.txt"]
    st.close()


def test_create_refuses_existing_study(tmp_path):
    Study.create(tmp_path / "s").close()
    with pytest.raises(StudyError, match="already holds a study"):
        Study.create(tmp_path / "s")


def test_invalid_manifests_are_named(tmp_path):
    folder = tmp_path / "s"
    Study.create(folder).close()
    man = folder / "study.json"
    good = json.loads(man.read_text())

    def opens_with(doc_or_text, match):
        man.write_text(doc_or_text if isinstance(doc_or_text, str) else json.dumps(doc_or_text))
        with pytest.raises(StudyError, match=match):
            Study.open(folder)

    truncated = '{"format": "talus-study", "schema_version": 2,'
    opens_with(truncated, r"study\.json: line 1 column \d+: invalid JSON")
    opens_with("[1, 2]", "expected a JSON object")
    opens_with({**good, "format": "xma"}, "not a Talus study")
    newer = r"schema_version 3 was written by a newer Talus.*up to schema version 2"
    opens_with({**good, "schema_version": 3}, newer)
    opens_with({**good, "schema_version": "2"}, "schema_version: expected a positive integer")
    bad = copy.deepcopy(good)
    bad["trials"]["t1"] = {"calibration": "nope", "views": [{"path": "a"}]}
    opens_with(bad, r"trials\['t1'\]\.calibration: no calibration named 'nope'")
    bad = copy.deepcopy(good)
    bad["volumes"]["ct"] = {"path": "ct.nii", "voxel_size_mm": [1, 1]}
    opens_with(bad, r"volumes\['ct'\]\.voxel_size_mm: expected a list of 3 positive voxel sizes")
    opens_with({**good, "colour": 1}, "unknown key 'colour'")
    del good["settings"]
    opens_with(good, "missing required key 'settings'")
    opens_with('{"format": "talus-study", "schema_version": NaN}', "strict JSON numbers")
    man.write_bytes(b"\xff\xfe\x00")
    with pytest.raises(StudyError, match="UTF-8"):
        Study.open(folder)
    for mode in ("r", "w"):  # a missing folder is named as such, not as its lock file
        with pytest.raises(StudyError, match=r"elsewhere: study folder does not exist") as err:
            Study.open(tmp_path / "elsewhere", mode=mode)
        assert ".talus.lock" not in str(err.value) and not (tmp_path / "elsewhere").exists()
    (tmp_path / "empty").mkdir()
    with pytest.raises(StudyError, match="not a Talus study folder"):
        Study.open(tmp_path / "empty", mode="w")
    assert not (tmp_path / "empty" / ".talus.lock").exists()  # no lock file left in a non-study


def test_validation_cross_references():
    doc = new_manifest("x")
    doc["calibrations"]["c"] = {"format": "mayacam", "cameras": ["a.txt", "b.txt"], "pixel_size_mm": None}
    doc["trials"]["t"] = {"calibration": "c", "views": [{"path": "v1"}]}
    with pytest.raises(StudyError, match=r"views: expected 2 view\(s\), one per camera"):
        validate_manifest(doc)
    doc["trials"]["t"]["views"].append({"path": "v2", "bit_depth": 11})
    with pytest.raises(StudyError, match=r"views\[1\]\.bit_depth: expected one of 8, 10, 12, 14, 16"):
        validate_manifest(doc)
    doc["trials"]["t"]["views"][1]["bit_depth"] = None
    doc["trials"]["t"]["bones"] = ["talus"]
    with pytest.raises(StudyError, match=r"bones\[0\]: no bone named 'talus'"):
        validate_manifest(doc)
    doc["bones"]["bad name!"] = {"volume": "v"}
    with pytest.raises(StudyError, match="entry name 'bad name!'"):
        validate_manifest(doc)


def test_missing_referenced_file_is_named(tmp_path, rig_files, views):
    _study(tmp_path, rig_files, views).close()
    rig_files[1].unlink()
    msg = r"calibrations\['day1'\]\.cameras\[1\]: referenced file .*cam2\.txt does not exist"
    with pytest.raises(StudyError, match=msg):
        Study.open(tmp_path / "st")
    st = Study.open(tmp_path / "st", check_files=False)
    assert [w for w, _ in st.missing_files()] == ["calibrations['day1'].cameras[1]"]


def test_failed_edit_writes_nothing(tmp_path, rig_files, views, monkeypatch):
    st = _study(tmp_path, rig_files, views)
    man = st.folder / "study.json"
    before = man.read_bytes()
    with pytest.raises(StudyError, match=r"views\[0\]: referenced file .* does not exist"):
        st.add_trial("t2", [tmp_path / "nope", views[0][1]], calibration="day1")
    with pytest.raises(ValueError, match="name: expected 1-64 letters"):
        st.add_calibration("bad name", rig_files)
    with pytest.raises(StudyError, match="no calibration named 'x'"):
        st.add_trial("t2", views[0], calibration="x")
    monkeypatch.setattr(atomic.os, "replace", lambda a, b: (_ for _ in ()).throw(OSError("injected")))
    with pytest.raises(OSError, match="injected"):
        st.update_settings(a=1)
    monkeypatch.undo()
    assert man.read_bytes() == before
    assert st.settings == {}  # the in-memory manifest did not change either
    assert not [p for p in st.folder.iterdir() if p.name.endswith(".tmp")]
    st.close()


def test_trial_view_checks(tmp_path, rig_files, views, make_tiff_folder):
    st = Study.create(tmp_path / "st")
    st.add_calibration("day1", rig_files)
    short = make_tiff_folder(tmp_path / "short", 5)
    with pytest.raises(ValueError, match=r"mismatched frame counts: .*cam1 has 6 frames, .*short has 5"):
        st.add_trial("t", [views[0][0], short], calibration="day1")
    wide = make_tiff_folder(tmp_path / "wide", 6, shape=(32, 40))
    msg = r"views\[1\]: .*wide has frames of 40x32 pixels but camera 'cam2' expects 32x32"
    with pytest.raises(StudyError, match=msg):
        st.add_trial("t", [views[0][0], wide], calibration="day1")
    with pytest.raises(ValueError, match="expected 2 sequence paths"):
        st.add_trial("t", [views[0][0]], calibration="day1")
    assert st.trials == ()
    st.close()


def test_relocate_a_moved_file(tmp_path, rig_files, views):
    _study(tmp_path, rig_files, views).close()
    moved = tmp_path / "elsewhere" / rig_files[1].name
    moved.parent.mkdir()
    rig_files[1].rename(moved)
    st = Study.open(tmp_path / "st", mode="w", check_files=False)
    (_what, path), = st.missing_files()
    with pytest.raises(StudyError, match="does not exist"):
        st.relocate(path, tmp_path / "nowhere.txt")
    with pytest.raises(StudyError, match="is not referenced"):
        st.relocate(tmp_path / "other.txt", moved)
    assert st.relocate(path, moved) == 1
    assert st.missing_files() == []
    st.close()
    with Study.open(tmp_path / "st") as again:  # saved, and the rig loads from the new place
        assert len(again.rig("day1")) == 2

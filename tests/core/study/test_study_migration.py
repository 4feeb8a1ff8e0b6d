import json

import pytest

from core.study import SCHEMA_VERSION, Study, StudyError
from core.study.migrations import migrate


def _v1(rig_files, views, ct):
    return {
        "format": "talus-study",
        "schema_version": 1,
        "name": "old study",
        "created": "2024-05-01T10:00:00+00:00",
        "modified": "2024-05-01T10:00:00+00:00",
        "cameras": [str(p) for p in rig_files],
        "pixel_size_mm": 0.3,
        "bones": [
            {"name": "talus", "ct": str(ct), "label": 3},
            {"name": "calcaneus", "ct": str(ct), "label": 4},
        ],
        "trials": [{"name": "walk01", "views": [str(p) for p in views[0]], "offset": 2}],
        "settings": {"metric": "ncc"},
    }


def test_v1_migrates_forward(tmp_path, rig_files, views):
    ct = tmp_path / "ct.nii.gz"
    ct.write_bytes(b"placeholder")  # referenced, not read by opening the study
    labels = tmp_path / "labels.nii.gz"
    labels.write_bytes(b"placeholder")
    folder = tmp_path / "st"
    folder.mkdir()
    v1 = _v1(rig_files, views, ct)
    (folder / "study.json").write_text(json.dumps(v1))
    with Study.open(folder) as ro:  # read-only: migrated in memory, file untouched
        assert ro.migrated_from == 1
        m = ro.manifest
        assert m["schema_version"] == SCHEMA_VERSION
        assert m["calibrations"]["default"]["pixel_size_mm"] == 0.3
        assert m["volumes"] == {"ct1": {"path": str(ct)}}  # one CT shared by both bones
        assert m["bones"]["calcaneus"] == {"volume": "ct1", "label": 4, "margin_mm": 5.0}
        assert m["trials"]["walk01"]["bones"] == ["talus", "calcaneus"]
        assert m["trials"]["walk01"]["frame_offset"] == 2
        assert ro.settings == {"metric": "ncc"}
        assert ro.trial("walk01").n_frames == 4  # 6 frames per view, view 1 two frames ahead
    assert json.loads((folder / "study.json").read_text())["schema_version"] == 1
    with Study.open(folder, mode="w") as rw:  # write mode saves the migrated manifest + a backup
        assert rw.migrated_from == 1
    assert json.loads((folder / "study.json").read_text())["schema_version"] == SCHEMA_VERSION
    assert json.loads((folder / "study.json.v1.bak").read_text()) == v1
    with Study.open(folder) as again:
        assert again.migrated_from == SCHEMA_VERSION


def test_v1_missing_fields_are_named(rig_files, views, tmp_path):
    v1 = _v1(rig_files, views, tmp_path / "ct.nii")
    del v1["cameras"]
    with pytest.raises(StudyError, match=r"x\.json: \(schema version 1\) cameras: expected a list"):
        migrate(v1, source="x.json")
    v1 = _v1(rig_files, views, tmp_path / "ct.nii")
    v1["trials"][0].pop("views")
    with pytest.raises(StudyError, match=r"trials\[0\]: expected name and views"):
        migrate(v1, source="x.json")


def test_migration_does_not_modify_input(rig_files, views, tmp_path):
    v1 = _v1(rig_files, views, tmp_path / "ct.nii")
    snapshot = json.dumps(v1)
    out, version = migrate(v1)
    assert version == 1 and out["schema_version"] == SCHEMA_VERSION
    assert json.dumps(v1) == snapshot

"""The study folder stays the study's: stale temporaries cleared, no escape through symbolic links,
names without a trailing newline, errors that name the folder (not its lock file)."""

import os
import stat
import time

import pytest

from core.errors import FileError
from core.study import LockedError, Study, StudyError


def _study(tmp_path, rig_files, views):
    st = Study.create(tmp_path / "st", name="subject07")
    st.add_calibration("day1", rig_files)
    st.add_trial("walk01", views[0], calibration="day1", bit_depth=12)
    return st


def test_stale_temporaries_are_removed_when_opened_for_writing(tmp_path, rig_files, views):
    _study(tmp_path, rig_files, views).close()
    folder = tmp_path / "st"
    (folder / "results" / "walk01").mkdir(parents=True)
    old = time.time() - 3600
    stale = [folder / ".study.json.k2j4h6g8.tmp", folder / "results" / "walk01" / ".talus.jsonl.abcdefgh.tmp"]
    young = folder / ".study.json.q1w2e3r4.tmp"  # a writer that is still running (not ours)
    for p in [*stale, young]:
        p.write_text("{")
    for p in stale:
        os.utime(p, (old, old))
    with Study.open(folder):  # read-only: touches nothing
        pass
    assert all(p.exists() for p in stale)
    with Study.open(folder, mode="w") as st:
        assert st.trials == ("walk01",)
    assert not any(p.exists() for p in stale) and young.exists()


def test_symlinked_results_outside_the_study_are_refused(tmp_path, rig_files, views):
    _study(tmp_path, rig_files, views).close()
    folder = tmp_path / "st"
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    (folder / "results").symlink_to(outside)
    for mode in ("r", "w"):
        with pytest.raises(StudyError, match=r"results: is a symbolic link to .*elsewhere, outside"):
            Study.open(folder, mode=mode)
    (folder / "results").unlink()
    (folder / "results" / "reports").mkdir(parents=True)
    (folder / "results" / "reports" / "calibration").symlink_to(outside)  # deeper down too
    with pytest.raises(StudyError, match=r"calibration: is a symbolic link"):
        Study.open(folder, mode="w")
    (folder / "results" / "reports" / "calibration").unlink()
    inside = folder / "results" / "kept"
    inside.mkdir()
    (folder / "results" / "walk01").symlink_to(inside)  # a link inside the study is fine
    with Study.open(folder, mode="w") as st:
        st.write_report("calibration", "day1", {"rms_px": 0.2})
        assert st.read_report("calibration", "day1") == {"rms_px": 0.2}
        (folder / "results" / "reports" / "qa").symlink_to(outside)  # appeared while open
        with pytest.raises(StudyError, match="outside the study folder"):
            st.write_report("qa", "x", {})
    assert not any(outside.iterdir())


@pytest.mark.parametrize("bad", ["walk01\n", "walk01\r\n", "\nwalk01", "walk 01", "", "a" * 65])
def test_names_with_a_trailing_newline_are_refused(tmp_path, rig_files, views, bad):
    with _study(tmp_path, rig_files, views) as st:
        with pytest.raises(ValueError, match="expected 1-64 letters"):
            st.add_calibration(bad, rig_files)
        with pytest.raises(ValueError, match="expected 1-64 letters"):
            st.write_report("calibration", bad, {})
    doc = (tmp_path / "st" / "study.json").read_text()
    (tmp_path / "st" / "study.json").write_text(doc.replace('"day1"', '"day1\\n"'))
    with pytest.raises(StudyError, match=r"entry name 'day1\\n'"):
        Study.open(tmp_path / "st")


def test_missing_or_locked_study_errors_are_readable(tmp_path, rig_files, views):
    for mode in ("r", "w"):
        with pytest.raises(StudyError, match=r"nowhere: study folder does not exist") as err:
            Study.open(tmp_path / "nowhere", mode=mode)
        assert isinstance(err.value, FileError) and err.value.path == tmp_path / "nowhere"
    import core.study.study as study_module
    from core.io.atomic import FileLock

    with _study(tmp_path, rig_files, views) as st, FileLock(tmp_path / "st" / ".talus.lock"):
        # another writer is updating the manifest (for longer than an update waits)
        study_module.MANIFEST_LOCK_S, wait = 0.05, study_module.MANIFEST_LOCK_S
        try:
            with pytest.raises(LockedError) as err:
                st.update_settings(a=1)
        finally:
            study_module.MANIFEST_LOCK_S = wait
    msg = str(err.value)
    assert f"manifest of study {tmp_path / 'st'} is locked for writing by process {os.getpid()} on " in msg
    assert "since 20" in msg and "open it read-only" in msg
    assert err.value.holder["pid"] == os.getpid()


def test_study_files_honour_the_umask(tmp_path, rig_files, views):
    old = os.umask(0o002)  # a lab's shared group folder
    try:
        with _study(tmp_path, rig_files, views) as st:
            st.write_report("calibration", "day1", {"rms_px": 0.2})
        reports = tmp_path / "st" / "results" / "reports"
        for p in (tmp_path / "st" / "study.json", reports / "calibration" / "day1.json"):
            assert stat.S_IMODE(p.stat().st_mode) == 0o664, p
    finally:
        os.umask(old)

"""``talus track`` on a trial with a damaged frame file: the frame's flag names the file and the
reader's error, and the other view's file is still read (it said 'frame missing in view 0, 1',
naming no file: the frame reader read both views at once and swallowed the error)."""

from __future__ import annotations

import json

import pytest

from app.cli import main as talus
from tests.app._helpers import small_demo


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    return small_demo(tmp_path_factory.mktemp("demo") / "study")


def test_a_damaged_frame_is_flagged_with_its_file_and_the_reason(demo, tmp_path, capsys):
    import shutil

    study = shutil.copytree(demo, tmp_path / "study")
    damaged = sorted((study / "frames").iterdir())[0] / "frame_0001.tif"
    damaged.write_bytes(b"II*\x00" + b"\x00" * 12)  # a TIFF header, no page
    talus(["track", str(study), "--trial", "walk", "--bones", "talus", "--frames", "1:2",
           "--device", "cpu", "--no-confidence"])
    out = capsys.readouterr()
    line = next(ln for ln in out.err.splitlines() if "flagged talus@1" in ln)
    assert f"frame cannot be read: view 1: {damaged}: " in line, line
    assert "view 2" not in line and "frame missing" not in line
    flagged = json.loads(out.out)["flagged"]
    assert any(str(damaged) in " ".join(flags) for _, _, flags in flagged)


def test_the_reader_reads_each_view_alone(demo, tmp_path):
    import shutil

    from core.study import Study
    from core.tracking.from_study import frame_reader

    study = shutil.copytree(demo, tmp_path / "study")
    damaged = sorted((study / "frames").iterdir())[1] / "frame_0001.tif"
    damaged.write_bytes(b"not a TIFF")
    with Study.open(study) as st:
        read, _ = frame_reader(st, st.trial("walk"))
        first, second = read(1)
        assert first is not None and second is None
        assert read.unreadable[1].startswith(f"view 2: {damaged}: ")
        assert all(im is not None for im in read(0)) and 0 not in read.unreadable


def test_the_readers_reason_reaches_the_tracker_with_the_view(demo, tmp_path):
    """The reader's ``reason(frame, view)``: the frame feed hands the damaged view on as a
    MissingView carrying its file and error, the readable view as its image; the tracker's flag is
    built from it (core.tracking.frame_step.missing_flags), not rewritten afterwards."""
    import shutil

    from core.study import Study
    from core.tracking.feed import FrameFeed, MissingView
    from core.tracking.frame_step import missing_flags
    from core.tracking.from_study import frame_reader

    study = shutil.copytree(demo, tmp_path / "study")
    damaged = sorted((study / "frames").iterdir())[1] / "frame_0001.tif"
    damaged.write_bytes(b"not a TIFF")
    with Study.open(study) as st:
        read, _ = frame_reader(st, st.trial("walk"))
        feed = FrameFeed(read, (0.02, 0.999), 3)
        try:
            imgs, prepared = feed.get(1)
        finally:
            feed.close()
        assert read.reason(1, 0) is None and read.reason(1, 1).startswith(f"{damaged}: ")
    assert imgs[0] is not None and isinstance(imgs[1], MissingView) and prepared is None
    (flag,) = missing_flags(imgs)
    assert flag.startswith(f"frame cannot be read: view 2: {damaged}: "), flag

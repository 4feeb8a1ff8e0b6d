"""app.demo_cache.complete_demo: the one "is this folder a complete demo" check of ``talus demo``
and the welcome page (files written by hand; nothing rendered)."""

import json

from app.demo_cache import DEMO_FORMAT, complete_demo


def _demo(folder, **summary):
    folder.mkdir(parents=True, exist_ok=True)
    doc = {"format": DEMO_FORMAT, "status": "complete", "n_frames": 3, "pixels": 64, "seed": 0,
           "study": "study.json", "calibration_session": "calibration_session", **summary}
    (folder / "summary.json").write_text(json.dumps(doc))
    (folder / "study.json").write_text("{}")
    (folder / "calibration_session").mkdir(exist_ok=True)
    (folder / "calibration_session" / "session.json").write_text("{}")
    return doc


def test_a_complete_demo_and_its_options(tmp_path):
    doc = _demo(tmp_path)
    assert complete_demo(tmp_path) == doc
    assert complete_demo(tmp_path, options={"n_frames": 3, "pixels": None, "seed": 0}) == doc
    assert complete_demo(tmp_path, options={"pixels": 128}) is None


def test_what_is_not_a_complete_demo(tmp_path):
    assert complete_demo(tmp_path / "nothing") is None
    _demo(tmp_path / "a", status="cancelled")
    assert complete_demo(tmp_path / "a", calibration_session=False) is None
    _demo(tmp_path / "b", format="something else")
    assert complete_demo(tmp_path / "b", calibration_session=False) is None
    _demo(tmp_path / "c")
    (tmp_path / "c" / "study.json").unlink()
    assert complete_demo(tmp_path / "c", calibration_session=False) is None
    (tmp_path / "d").mkdir()
    (tmp_path / "d" / "summary.json").write_text("{ broken")
    assert complete_demo(tmp_path / "d") is None


def test_the_calibration_session_is_needed_unless_told(tmp_path):
    """The welcome page opens a demo written without a calibration session; ``talus demo``
    rebuilds it."""
    doc = _demo(tmp_path, calibration_session=None)
    assert complete_demo(tmp_path) is None
    assert complete_demo(tmp_path, calibration_session=False) == doc
    _demo(tmp_path)
    (tmp_path / "calibration_session" / "session.json").unlink()
    assert complete_demo(tmp_path) is None
    assert complete_demo(tmp_path, calibration_session=False) is not None

"""``talus track`` and ``talus batch``: the first frame's backward check (``--backward-limit K|off``,
``--no-backward-check``; ``TrackingOptions.backward_limit``) parsed, checked and handed to the tracker
(not run here), its choice round-tripping through the window's mapping, and its help."""

from __future__ import annotations

import pytest

from app.cli import EXIT_NOTHING_DONE, EXIT_OK
from app.cli import main as talus
from app.commands import track
from core.tracking.backward_check import LIMIT
from core.tracking.options import TrackingOptions
from tests.app._helpers import copy_study, track_options_spy


@pytest.fixture
def study(demo_study, tmp_path):
    return copy_study(demo_study, tmp_path)


@pytest.fixture
def tracker(monkeypatch):
    """track_study replaced: the options of each call, nothing tracked."""
    return track_options_spy(monkeypatch)


def test_the_default_and_off_round_trip():
    assert track.CHECKS["backward_limit"][1] == TrackingOptions().backward_limit == LIMIT == 1.25
    assert track.check_choices(None)["backward_limit"] == 1.25
    for value in (None, 1.0, 2.0):
        o = track.options_from_choices(backward_limit=value)
        assert o.backward_limit == value and track.choices_of(o)["backward_limit"] == value
        assert track.options_from_choices(**track.choices_of(o)) == o
    both = track.options_from_choices(backward_limit=None, trajectory_limit=None)
    assert (both.backward_limit, both.trajectory_limit) == (None, None)
    for bad in (0, -1.0, float("nan"), "1"):
        with pytest.raises(ValueError, match=r"^backward_limit: expected a"):
            TrackingOptions(backward_limit=bad)
    for under in (0.5, 0.999):  # under 1, as the trajectory limit: refused, the range named
        with pytest.raises(ValueError, match=r"^backward_limit: expected a factor >= 1 .* or None \(off\), "
                                             rf"got {under}$"):
            TrackingOptions(backward_limit=under)


@pytest.mark.parametrize(("flags", "expected"), [
    ([], 1.25), (["--backward-limit", "2"], 2.0), (["--backward-limit", "1"], 1.0),
    (["--backward-limit", "off"], None), (["--no-backward-check"], None),
    (["--no-backward-check", "--no-trajectory-check"], None)])
def test_the_backward_check_reaches_track_and_batch(study, tracker, monkeypatch, capsys, flags, expected):
    import core.tracking.batch as core_batch

    settings = []
    monkeypatch.setattr(core_batch, "run_serial",
                        lambda tasks, s, progress=None: settings.append(s) or {"status": "complete",
                                                                               "failures": []})
    assert talus(["track", str(study), "--trial", "walk", "--frames", "0:1", "--quiet", *flags]) \
        == EXIT_NOTHING_DONE
    assert talus(["batch", str(study), "--workers", "0", "--quiet", *flags]) == EXIT_OK
    capsys.readouterr()
    assert tracker[0].backward_limit == expected
    assert tracker[0].trajectory_limit == (None if "--no-trajectory-check" in flags else 2.5)  # its own
    for joint in (False, True):
        assert settings[0].tracking_options(joint=joint).backward_limit == expected


def test_a_bad_limit_and_both_spellings_are_refused(study, tracker, capsys):
    for command in ("track", "batch"):
        extra = ["--trial", "walk"] if command == "track" else ["--workers", "0"]
        for under in ("0", "0.75"):
            assert talus([command, str(study), *extra, "--quiet", "--backward-limit", under]) == 1
            err = capsys.readouterr().err
            assert "--backward-limit: expected a factor >= 1 (times the bone's median trajectory " \
                   f"residual) or None (off), got {float(under)}" in err, err
        with pytest.raises(SystemExit) as e:
            talus([command, str(study), *extra, "--backward-limit", "3", "--no-backward-check"])
        assert e.value.code == 2
        err = capsys.readouterr().err
        assert "--no-backward-check" in err and "--backward-limit" in err and "not allowed" in err
        with pytest.raises(SystemExit):
            talus([command, str(study), *extra, "--backward-limit", "high"])
        assert "expected a factor or 'off'" in capsys.readouterr().err
    assert tracker == []  # nothing started


def test_help_names_the_backward_check(capsys):
    for command in ("track", "batch"):
        with pytest.raises(SystemExit):
            talus([command, "--help"])
        text = " ".join(capsys.readouterr().out.split())
        assert "--backward-limit K|off" in text and "--no-backward-check" in text
        assert "first frame off its backward registration" in text and "default 1.25" in text
        assert "1.46 and 1.72 times" in text and "a factor >= 1 or off, default 1.25" in text


def test_the_report_records_the_limit_used(study, monkeypatch, capsys):
    """The tracking report's options (written as the run starts) say which limit the run used (null:
    the check off); the renderer and the frame loop replaced, nothing tracked."""
    import core.render
    import core.tracking.from_study as from_study
    from core.study import Study

    def no_run(renderer, models, *args, **kw):
        return from_study.TrackingResult(tuple(m.name for m in models), (), {}, "complete", 0.0)

    monkeypatch.setattr(core.render, "DRRRenderer", lambda *a, **k: None)
    monkeypatch.setattr(from_study, "track", no_run)
    # the default's entry: test_cli_track (a real run)
    talus(["track", str(study), "--trial", "walk", "--bones", "talus", "--frames", "1:2", "--device", "cpu",
           "--quiet", "--no-backward-check"])
    capsys.readouterr()
    with Study.open(study) as st:
        options = st.read_report("tracking", "walk")["options"]
    assert options["backward_limit"] is None and options["trajectory_limit"] == 2.5

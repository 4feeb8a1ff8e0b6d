"""``talus track`` and ``talus batch``: the failure checks' thresholds (--collapse-ratio,
--motion-limit, --motion-floor, --sigma-limit), the final stage's move check (--stage-move-limit,
--stage-move-sigmas, --stage-move-frames, --keep-stage-moves) and the trajectory check
(--trajectory-limit K|off, --no-trajectory-check) parsed, checked and handed to the
tracker (which is not run here), and the likelihood final stage refused after one read of the
trial's correction."""

from __future__ import annotations

import pytest

from app.cli import EXIT_NOTHING_DONE, EXIT_OK
from app.cli import main as talus
from app.commands import track
from core.tracking.options import CHECK_FIELDS, STAGE_MOVE_FIELDS, TrackingOptions
from tests.app._helpers import copy_study, track_options_spy

FLAGS = ["--collapse-ratio", "0.5", "--motion-limit", "4", "--motion-floor", "0.5,1.5",
         "--sigma-limit", "2.5"]
GIVEN = {"collapse_ratio": 0.5, "motion_limit": 4.0, "motion_floor": (0.5, 1.5), "sigma_limit": 2.5}
STAGE_FLAGS = ["--final", "likelihood", "--stage-move-limit", "3", "--stage-move-sigmas", "0.25",
               "--stage-move-frames", "8", "--keep-stage-moves"]
STAGE_GIVEN = {"stage_move_limit": 3.0, "stage_move_sigmas": 0.25, "stage_move_frames": 8,
               "stage_move_reject": False}


@pytest.fixture
def study(demo_study, tmp_path):
    return copy_study(demo_study, tmp_path)


@pytest.fixture
def tracker(monkeypatch):
    """track_study replaced: the options of each call, nothing tracked."""
    return track_options_spy(monkeypatch)


def test_the_command_line_defaults_are_the_trackers():
    o = TrackingOptions()
    fields = {**CHECK_FIELDS, **STAGE_MOVE_FIELDS, "trajectory_limit": None, "backward_limit": None}
    assert set(track.CHECKS) == set(fields) and set(track.STAGE_MOVES) == set(STAGE_MOVE_FIELDS)
    assert {k: d for k, (_, d, _) in track.CHECKS.items()} == {k: getattr(o, k) for k in fields}
    assert track.check_choices(track.options_from_choices()) == track.check_choices(None)
    custom = track.options_from_choices(collapse_ratio=0.5, motion_floor=(0.5, 1.5))
    c = track.choices_of(custom)
    assert c["collapse_ratio"] == 0.5 and c["motion_floor"] == (0.5, 1.5)
    assert track.options_from_choices(**c) == custom  # the choices round-trip
    staged = track.options_from_choices(final="likelihood", **STAGE_GIVEN)
    c = track.choices_of(staged)
    assert {k: c[k] for k in STAGE_GIVEN} == STAGE_GIVEN and type(c["stage_move_frames"]) is int
    assert track.options_from_choices(**c) == staged
    off = track.options_from_choices(trajectory_limit=None)
    assert off.trajectory_limit is None and track.choices_of(off)["trajectory_limit"] is None
    assert track.options_from_choices(**track.choices_of(off)) == off


@pytest.mark.parametrize(("flags", "expected"), [
    ([], 2.5), (["--trajectory-limit", "3.5"], 3.5), (["--trajectory-limit", "off"], None),
    (["--no-trajectory-check"], None)])
def test_the_trajectory_check_reaches_track_and_batch(study, tracker, monkeypatch, capsys, flags, expected):
    import core.tracking.batch as core_batch

    settings = []
    monkeypatch.setattr(core_batch, "run_serial",
                        lambda tasks, s, progress=None: settings.append(s) or {"status": "complete",
                                                                               "failures": []})
    assert talus(["track", str(study), "--trial", "walk", "--frames", "0:1", "--quiet", *flags]) \
        == EXIT_NOTHING_DONE
    assert talus(["batch", str(study), "--workers", "0", "--quiet", *flags]) == EXIT_OK
    capsys.readouterr()
    assert tracker[0].trajectory_limit == expected
    for joint in (False, True):
        assert settings[0].tracking_options(joint=joint).trajectory_limit == expected


def test_help_names_the_trajectory_check_and_its_effect(capsys):
    with pytest.raises(SystemExit):
        talus(["track", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--trajectory-limit K|off" in text and "--no-trajectory-check" in text
    assert "off the trajectory" in text and "from 5 to 1" in text and "14 of 295" in text
    assert "1.50/1.42" in text and "13.9 ms per bone-frame" in text  # --final's current numbers


def test_help_names_the_move_check_and_its_final_stage(capsys):
    with pytest.raises(SystemExit):
        talus(["track", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    for flag in ("--stage-move-limit K", "--stage-move-sigmas S", "--stage-move-frames N",
                 "--keep-stage-moves"):
        assert flag in text
    assert "final stage move check" in text and text.count("with --final likelihood only") >= 4
    assert "default 4" in text and "default 0.5" in text and "default 5" in text


def test_talus_track_hands_the_thresholds_to_the_tracker(study, tracker, capsys):
    args = ["track", str(study), "--trial", "walk", "--frames", "0:1", "--quiet"]
    assert talus(args) == EXIT_NOTHING_DONE
    assert talus([*args, *FLAGS]) == EXIT_NOTHING_DONE
    capsys.readouterr()
    plain, custom = tracker
    defaults = {k: getattr(TrackingOptions(), k) for k in CHECK_FIELDS}
    assert {k: getattr(plain, k) for k in CHECK_FIELDS} == defaults
    assert {k: getattr(custom, k) for k in CHECK_FIELDS} == GIVEN
    from dataclasses import replace

    assert replace(custom, **defaults) == plain  # nothing else changed


def test_talus_track_hands_the_move_check_to_the_tracker(study, tracker, capsys):
    args = ["track", str(study), "--trial", "walk", "--frames", "0:1", "--quiet"]
    assert talus([*args, *STAGE_FLAGS]) == EXIT_NOTHING_DONE
    assert "no effect" not in capsys.readouterr().err
    assert talus([*args, "--stage-move-limit", "3"]) == EXIT_NOTHING_DONE  # without the stage: a note
    err = capsys.readouterr().err
    assert "--stage-move-limit: no effect without --final likelihood" in err
    staged, plain = tracker
    assert staged.refine_likelihood and {k: getattr(staged, k) for k in STAGE_GIVEN} == STAGE_GIVEN
    assert type(staged.stage_move_frames) is int
    assert not plain.refine_likelihood and plain.stage_move_limit == 3.0


@pytest.mark.parametrize(("flag", "value", "expected"), [
    ("--collapse-ratio", "1.2", "--collapse-ratio: expected a ratio in [0, 1]"),
    ("--motion-limit", "0.5", "--motion-limit: expected a factor >= 1"),
    ("--motion-floor", "1", "--motion-floor: expected MM,DEG"),
    ("--motion-floor", "1,-2", "--motion-floor: expected (mm, degrees), each a number >= 0"),
    ("--sigma-limit", "nan", "--sigma-limit: expected a finite number"),
    ("--stage-move-limit", "0.5", "--stage-move-limit: expected a factor >= 1"),
    ("--stage-move-sigmas", "-1", "--stage-move-sigmas: expected a factor >= 0"),
    ("--stage-move-frames", "2.5", "--stage-move-frames: expected an integer >= 1"),
    ("--stage-move-frames", "0", "--stage-move-frames: expected an integer >= 1"),
    ("--trajectory-limit", "0.5", "--trajectory-limit: expected a factor >= 1"),
])
def test_bad_thresholds_are_refused_naming_the_option(study, tracker, capsys, flag, value, expected):
    for command in ("track", "batch"):
        extra = ["--trial", "walk"] if command == "track" else ["--workers", "0"]
        assert talus([command, str(study), *extra, "--quiet", flag, value]) == 1
        err = capsys.readouterr().err
        assert expected in err, err
    assert tracker == []  # nothing started


def test_talus_batch_hands_the_thresholds_to_every_task(study, monkeypatch, capsys):
    import core.tracking.batch as core_batch
    from app.commands import batch as batch_command

    seen = []

    def fake_run_serial(tasks, settings, progress=None):
        seen.append(settings)
        return {"status": "complete", "failures": []}

    monkeypatch.setattr(core_batch, "run_serial", fake_run_serial)
    assert talus(["batch", str(study), "--workers", "0", "--quiet"]) == EXIT_OK
    assert talus(["batch", str(study), "--workers", "0", "--quiet", *FLAGS]) == EXIT_OK
    capsys.readouterr()
    plain, custom = seen[:2]
    defaults = {k: getattr(TrackingOptions(), k) for k in CHECK_FIELDS}
    for joint in (False, True):
        assert {k: getattr(plain.tracking_options(joint=joint), k) for k in CHECK_FIELDS} == defaults
        assert {k: getattr(custom.tracking_options(joint=joint), k) for k in CHECK_FIELDS} == GIVEN
    # the move check, with the final stage (every trial must be flatfield-corrected: asked of none here)
    monkeypatch.setattr(batch_command, "final_stage_problems", lambda tasks: [])
    assert talus(["batch", str(study), "--workers", "0", "--quiet", *STAGE_FLAGS]) == EXIT_OK
    assert "no effect" not in capsys.readouterr().err
    for joint in (False, True):
        o = seen[2].tracking_options(joint=joint)
        assert o.refine_likelihood and {k: getattr(o, k) for k in STAGE_GIVEN} == STAGE_GIVEN
    assert talus(["batch", str(study), "--workers", "0", "--quiet", "--keep-stage-moves"]) == EXIT_OK
    assert "--keep-stage-moves: no effect without --final likelihood" in capsys.readouterr().err
    assert seen[3].tracking_options(joint=False).stage_move_reject is False


def test_the_final_stage_refusal_reads_the_correction_once(study, monkeypatch, capsys):
    """The demo's frames are divided by the full scale: track_study refuses --final likelihood
    (FinalStageError, exit 1, the trial named) after one frame_reader call, before the bones'
    journals are locked or their models built."""
    import core.tracking.from_study as from_study

    calls = []
    real = from_study.frame_reader
    monkeypatch.setattr(from_study, "frame_reader", lambda *a, **k: calls.append(1) or real(*a, **k))
    monkeypatch.setattr(from_study, "bone_model", lambda *a, **k: pytest.fail("a bone model was built"))
    rc = talus(["track", str(study), "--trial", "walk", "--bones", "talus", "--frames", "1:2",
                "--device", "cpu", "--final", "likelihood", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1 and "--final likelihood: trial 'walk'" in err and "not flatfield-corrected" in err
    assert len(calls) == 1 and "Traceback" not in err


def test_a_limit_and_no_trajectory_check_together_are_refused(study, capsys):
    with pytest.raises(SystemExit) as e:
        talus(["track", str(study), "--trial", "walk", "--trajectory-limit", "3", "--no-trajectory-check"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "--no-trajectory-check" in err and "--trajectory-limit" in err and "not allowed" in err

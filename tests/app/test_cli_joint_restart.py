"""talus track/batch --joint-restart and --joint-rounds N: parsed into ``TrackingOptions.joint_restart``
(off by default) and ``joint_rounds`` (1 by default; --joint-restart alone implies 2, --joint-rounds 1
--joint-restart refused naming both), listed in --help (with their measured cost) and the README, passed
to every batch task, and the report's record of them carried into ``talus track``'s JSON summary (the
note on stderr)."""

from __future__ import annotations

import argparse
import json
import re
from pathlib import Path

import pytest

from app.commands import batch, track
from app.commands._shared import EXIT_OK
from tests.app._helpers import parse_command, run_command

README = Path(__file__).resolve().parents[2] / "README.md"


def _parse(argv, command=track):
    return parse_command(argv, command)


def test_track_parses_the_flag_into_the_option():
    assert _parse(["study", "--trial", "walk"]).joint_restart is False
    assert track.options_from_choices().joint_restart is False
    assert track.choices_of(None)["joint_restart"] is False
    a = _parse(["study", "--trial", "walk", "--mode", "joint", "--joint-restart"])
    opts = track.options_from_choices(mode=a.mode, joint_restart=a.joint_restart)
    assert opts.joint_restart is True
    c = track.choices_of(opts)
    assert c["joint_restart"] is True and track.options_from_choices(**c) == opts  # round trip
    with pytest.raises(ValueError, match="joint_restart"):
        track.options_from_choices(joint_restart="yes")


def test_rounds_default_to_one_and_the_restart_implies_two():
    assert _parse(["study", "--trial", "walk"]).joint_rounds is None
    assert track.options_from_choices().joint_rounds == 1 and track.choices_of(None)["joint_rounds"] == 1
    assert track.options_from_choices(joint_restart=True).joint_rounds == 2  # --joint-restart alone
    for argv, rounds in ((["--joint-rounds", "3"], 3), (["--joint-rounds", "3", "--joint-restart"], 3),
                         (["--joint-restart"], None), (["--joint-rounds", "1"], 1)):
        a = _parse(["study", "--trial", "walk", "--mode", "joint", *argv])
        assert track.joint_rounds_of_args(a) == rounds
        opts = track.options_from_choices(mode="joint", joint_restart=a.joint_restart,
                                          joint_rounds=track.joint_rounds_of_args(a))
        assert opts.joint_rounds == (rounds or 2)
        c = track.choices_of(opts)
        assert c["joint_rounds"] == opts.joint_rounds and track.options_from_choices(**c) == opts


@pytest.mark.parametrize("command", ["track", "batch"])
@pytest.mark.parametrize(("argv", "error"), [
    (["--joint-rounds", "1", "--joint-restart"], "--joint-rounds 1 --joint-restart: the restart acts on the "
                                                 "rounds after the first"),
    (["--joint-rounds", "0"], "--joint-rounds: expected an integer >= 1 (rounds per frame), got 0"),
])
def test_bad_rounds_are_refused_naming_the_options(demo_study, capsys, command, argv, error):
    from app.cli import main as talus

    extra = ["--trial", "walk", "--device", "cpu"] if command == "track" else ["--workers", "0"]
    assert talus([command, str(demo_study), *extra, "--quiet", "--mode", "joint", *argv]) == 1
    assert error in capsys.readouterr().err


def test_help_and_readme_list_the_flag(capsys):
    for command in (track, batch):
        p = argparse.ArgumentParser()
        command.configure(p)
        p.print_help()
        out = " ".join(capsys.readouterr().out.split())
        assert "--joint-restart" in out and "182 evaluations" in out and "seed 3" in out, command.__name__
        assert "--joint-restart alone implies --joint-rounds 2" in out, command.__name__
        assert "--joint-rounds N" in out and "121.8 against 202.3" in out, command.__name__
        assert "--joint-restart" in command.__doc__ and "--joint-rounds N" in command.__doc__
    usage = README.read_text(encoding="utf-8")
    for name in ("track", "batch"):
        block = re.search(rf"^talus {name} .*?(?=^talus (?!{name}))", usage, re.M | re.S).group(0)
        assert "[--joint-rounds N] [--joint-restart]" in block, name
    bullets = usage.split("### `talus batch`")[0]
    assert "--joint-restart" in bullets and "seed 4" in bullets  # the track bullets say it, and why off
    assert "--joint-rounds N" in bullets


def test_batch_passes_the_flag_to_every_task(demo_study, capsys, monkeypatch):
    import core.tracking.batch as core_batch

    seen = []
    note = "resumed with joint restart on: the frames tracked before ran with it off"

    def fake_run_serial(tasks, settings, progress=None):
        seen.append(settings)
        return {"status": "complete", "failures": [], "task_records": [
            {"key": "demo/walk/talus+calcaneus", "mode": "joint", "joint_restart": True,
             "joint_restart_note": note}]}

    monkeypatch.setattr(core_batch, "run_serial", fake_run_serial)

    def talus_batch(argv):
        return run_command(argv, batch, "batch")

    for extra in ([], ["--joint-restart"], ["--joint-rounds", "3"]):
        argv = [str(demo_study), "--workers", "0", "--quiet", "--mode", "joint", *extra]
        assert talus_batch(argv) == EXIT_OK
        err = capsys.readouterr().err
    assert "demo/walk/talus+calcaneus: resumed with joint restart on" in err
    argv = [str(demo_study), "--workers", "0", "--quiet", "--mode", "sequential", "--joint-restart",
            "--joint-rounds", "2"]
    assert talus_batch(argv) == EXIT_OK
    assert "--joint-rounds, --joint-restart: no effect with --mode sequential" in capsys.readouterr().err
    seen.pop()
    got = [(o.joint_restart, o.joint_rounds) for o in (s.tracking_options(joint=True) for s in seen)]
    assert got == [(False, 1), (True, 2), (False, 3)]  # --joint-restart alone: two rounds


def test_track_summary_gives_the_record(demo_study, monkeypatch, capsys):
    """``talus track``'s JSON summary carries the report's ``joint_restart`` (and its note, also on
    stderr); the options the command built have it."""
    from app.cli import main as talus
    from core.tracking import from_study

    got = {}
    rep = {"summary": {"status": "complete"}, "options": {
        "mode": "joint", "joint_rounds": 2, "joint_restart": True,
        "joint_restart_note": "resumed with joint restart on: the frames tracked before ran with it off"}}

    def fake(*a, options=None, **k):
        got["options"] = options
        return None, rep

    monkeypatch.setattr(from_study, "track_study", fake)
    talus(["track", str(demo_study), "--trial", "walk", "--frames", "1:2", "--mode", "joint",
           "--joint-restart", "--device", "cpu", "--quiet", "--resume"])
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert got["options"].joint_restart is True and got["options"].joint_rounds == 2
    assert out["joint_restart"] is True and out["joint_restart_note"] == rep["options"]["joint_restart_note"]
    assert out["joint_rounds"] == 2
    assert "resumed with joint restart on" in cap.err
    talus(["track", str(demo_study), "--trial", "walk", "--mode", "sequential", "--joint-restart", "--device",
           "cpu", "--quiet"])
    assert "--joint-restart: no effect with --mode sequential" in capsys.readouterr().err

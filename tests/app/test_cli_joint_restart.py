"""talus track/batch --joint-restart: parsed into ``TrackingOptions.joint_restart`` (off by default),
listed in --help (with its measured cost) and the README, passed to every batch task, and the
report's record of it carried into ``talus track``'s JSON summary (the note on stderr)."""

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


def test_help_and_readme_list_the_flag(capsys):
    for command in (track, batch):
        p = argparse.ArgumentParser()
        command.configure(p)
        p.print_help()
        out = " ".join(capsys.readouterr().out.split())
        assert "--joint-restart" in out and "182 evaluations" in out and "seed 4" in out, command.__name__
        assert "--joint-restart" in command.__doc__
    usage = README.read_text(encoding="utf-8")
    for name in ("track", "batch"):
        block = re.search(rf"^talus {name} .*?(?=^talus (?!{name}))", usage, re.M | re.S).group(0)
        assert "[--joint-restart]" in block, name
    bullets = usage.split("### `talus batch`")[0]
    assert "--joint-restart" in bullets and "seed 4" in bullets  # the track bullets say it, and why off


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

    for extra in ([], ["--joint-restart"]):
        argv = [str(demo_study), "--workers", "0", "--quiet", "--mode", "joint", *extra]
        assert talus_batch(argv) == EXIT_OK
        err = capsys.readouterr().err
    assert "demo/walk/talus+calcaneus: resumed with joint restart on" in err
    argv = [str(demo_study), "--workers", "0", "--quiet", "--mode", "sequential", "--joint-restart"]
    assert talus_batch(argv) == EXIT_OK
    assert "--joint-restart: no effect with --mode sequential" in capsys.readouterr().err
    seen.pop()
    off, on = (s.tracking_options(joint=True).joint_restart for s in seen)
    assert (off, on) == (False, True)


def test_track_summary_gives_the_record(demo_study, monkeypatch, capsys):
    """``talus track``'s JSON summary carries the report's ``joint_restart`` (and its note, also on
    stderr); the options the command built have it."""
    from app.cli import main as talus
    from core.tracking import from_study

    got = {}
    rep = {"summary": {"status": "complete"}, "options": {
        "mode": "joint", "joint_restart": True,
        "joint_restart_note": "resumed with joint restart on: the frames tracked before ran with it off"}}

    def fake(*a, options=None, **k):
        got["options"] = options
        return None, rep

    monkeypatch.setattr(from_study, "track_study", fake)
    talus(["track", str(demo_study), "--trial", "walk", "--frames", "1:2", "--mode", "joint",
           "--joint-restart", "--device", "cpu", "--quiet", "--resume"])
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert got["options"].joint_restart is True
    assert out["joint_restart"] is True and out["joint_restart_note"] == rep["options"]["joint_restart_note"]
    assert "resumed with joint restart on" in cap.err
    talus(["track", str(demo_study), "--trial", "walk", "--mode", "sequential", "--joint-restart", "--device",
           "cpu", "--quiet"])
    assert "--joint-restart: no effect with --mode sequential" in capsys.readouterr().err

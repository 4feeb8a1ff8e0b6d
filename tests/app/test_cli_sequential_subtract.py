"""talus track/batch --sequential-subtract auto|on|off: parsed into
``TrackingOptions.sequential_subtract`` (auto: None, which track_study turns on for flatfield-corrected
frames), listed in --help and the README; and end to end on 128² frames on Warp's CPU device: in
sequential mode, auto searches each bone with its neighbour subtracted on flatfield-corrected frames
and alone on frames divided by the full scale."""

from __future__ import annotations

import argparse
import json
import re
import shutil
from pathlib import Path

import pytest

from app.commands import batch, track
from app.commands._shared import EXIT_OK
from tests.app._helpers import parse_command, run_command

README = Path(__file__).resolve().parents[2] / "README.md"


def _parse(argv, command=track):
    return parse_command(argv, command)


def test_track_parses_the_choice_into_the_option():
    a = _parse(["study", "--trial", "walk"])
    assert a.sequential_subtract == "auto"
    assert track.options_from_choices().sequential_subtract is None  # auto: track_study decides
    for choice, value in (("auto", None), ("on", True), ("off", False)):
        a = _parse(["study", "--trial", "walk", "--sequential-subtract", choice])
        opts = track.options_from_choices(sequential_subtract=a.sequential_subtract)
        assert opts.sequential_subtract is value
        c = track.choices_of(opts)
        assert c["sequential_subtract"] == choice and track.options_from_choices(**c) == opts  # round trip
    assert track.choices_of(None)["sequential_subtract"] == "auto"
    with pytest.raises(SystemExit):
        _parse(["study", "--trial", "walk", "--sequential-subtract", "yes"])
    with pytest.raises(ValueError, match="sequential_subtract"):
        track.options_from_choices(sequential_subtract=True)  # the choices are the command line's words


def test_help_and_readme_list_the_option(capsys):
    for command in (track, batch):
        p = argparse.ArgumentParser()
        command.configure(p)
        p.print_help()
        out = capsys.readouterr().out
        assert "--sequential-subtract {auto,on,off}" in out, command.__name__
        assert "--sequential-subtract auto|on|off" in command.__doc__
    usage = README.read_text(encoding="utf-8")
    for name in ("track", "batch"):
        block = re.search(rf"^talus {name} .*?(?=^talus (?!{name}))", usage, re.M | re.S).group(0)
        assert "[--sequential-subtract auto|on|off]" in block, name
    assert "--sequential-subtract" in usage.split("### `talus batch`")[0]  # the track bullets say it


def test_batch_passes_the_choice_to_every_task(demo_study, capsys, monkeypatch):
    import core.tracking.batch as core_batch

    seen = []

    def fake_run_serial(tasks, settings, progress=None):
        seen.append(settings)
        return {"status": "complete", "failures": []}

    monkeypatch.setattr(core_batch, "run_serial", fake_run_serial)

    def talus_batch(argv):
        return run_command(argv, batch, "batch")

    for choice in ("auto", "on", "off"):
        assert talus_batch([str(demo_study), "--workers", "0", "--quiet", "--sequential-subtract",
                            choice]) == EXIT_OK
        capsys.readouterr()
    auto, on, off = (s.tracking_options(joint=False).sequential_subtract for s in seen)
    assert (auto, on, off) == (None, True, False)


@pytest.fixture(scope="module")
def studies_128(tmp_path_factory):
    """The same 2-frame demo walk in 128² views (3 mm voxels) twice: as written (frames divided by
    the full scale) and with a saved flatfield correction of a uniform field (the same fluence,
    but the tracker finds the frames flatfield-corrected)."""
    from core.synthetic import make_demo_study
    from tests.core.tracking.batch_helpers import save_flat_calibration

    base = tmp_path_factory.mktemp("subtract_128")
    plain = base / "plain"
    make_demo_study(plain, n_frames=2, pixels=128, seed=3, device="cpu", spacing=3.0, tissue_spacing=6.0,
                    calibration_session=False)
    corrected = base / "corrected"
    shutil.copytree(plain, corrected)
    save_flat_calibration(corrected, ["walk"])
    return {False: plain, True: corrected}


@pytest.mark.parametrize("corrected", [True, False])
def test_auto_subtracts_on_flatfield_corrected_frames_only(studies_128, tmp_path, capsys, monkeypatch,
                                                           corrected):
    """``talus track --mode sequential`` (``--sequential-subtract`` auto) on 128² frames, tracked at
    half resolution (``--scale 2``: the order and the subtraction are checked, not the accuracy),
    Warp's CPU device, frame 0 tracked from the keyframes: the talus is searched first, then the
    calcaneus — where the frames are flatfield-corrected the talus with the calcaneus at its keyframe
    subtracted and the calcaneus with the talus just registered, against the whole image where they
    are divided by the full scale. The frames are the same in both studies; only the normalisation
    found differs."""
    import core.tracking.frame_step as fs
    from app.cli import main as talus

    folder = shutil.copytree(studies_128[corrected], tmp_path / "study")
    real, searched = fs.register_checked, []

    def spy(*a, **k):
        others = a[9]
        searched.append((a[3], None if others is None else list(others[1])))
        return real(*a, **k)

    monkeypatch.setattr(fs, "register_checked", spy)
    rc = talus(["track", str(folder), "--trial", "walk", "--bones", "talus,calcaneus", "--frames", "0:1",
                "--mode", "sequential", "--device", "cpu", "--no-confidence", "--no-trajectory-check",
                "--scale", "2", "--quiet"])
    out = json.loads(capsys.readouterr().out)
    assert rc == EXIT_OK
    assert out["sequential_subtract"] is corrected
    assert (out["normalisation"] != "full scale (no flatfield)") is corrected
    assert [b for b, _ in searched][:2] == [0, 1]  # the talus, then the calcaneus (a retry may follow)
    if corrected:  # every search with the other bone subtracted (the talus's: the calcaneus's keyframe)
        assert all(others == [1 - b] for b, others in searched)
    else:  # no search with a neighbour subtracted
        assert all(others is None for _, others in searched)
    report = json.loads((folder / "results" / "reports" / "tracking" / "walk.json").read_text())
    assert report["options"]["mode"] == "sequential"
    assert report["options"]["sequential_subtract"] is corrected

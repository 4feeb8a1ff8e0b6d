import json

import numpy as np
import pytest

from app.cli import EXIT_NOTHING_DONE
from app.cli import main as talus
from app.commands.track import parse_frames


def main(argv):
    return talus(["track", *argv])


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("demo")
    make_demo_study(out, n_frames=3, pixels=96, spacing=2.0, tissue_spacing=4.0, device="cpu",
                    calibration_session=False)
    return out


def test_parse_frames():
    assert parse_frames("2:5", 10) == [2, 3, 4]
    assert parse_frames(":2", 10) == [0, 1] and parse_frames("8:", 10) == [8, 9]
    assert parse_frames("3", 10) == [3] and parse_frames(None, 3) == [0, 1, 2]
    with pytest.raises(ValueError, match="--frames"):
        parse_frames("5:2", 10)
    with pytest.raises(ValueError, match="--frames"):
        parse_frames("a:b", 10)


def test_track_command_records_reports_and_resumes(demo, capsys):
    from core.study import Study

    rc = main([str(demo), "--trial", "walk", "--bones", "talus", "--frames", "1:2", "--device", "cpu",
               "--no-confidence", "--scale", "2"])  # half resolution: 2.8 s of CPU instead of 6.6
    out = capsys.readouterr()
    assert rc == 0, out.err
    doc = json.loads(out.out)
    assert doc["summary"]["results"] == 1 and isinstance(doc["normalisation"], str)
    assert "[" in out.err and "1/1" in out.err  # the progress bar
    with Study.open(demo) as st:
        P = st.trial("walk").poses("talus")
        assert np.all(np.isfinite(P[1])) and np.all(np.isnan(P[2]))
        rep = st.read_report("tracking", "walk")
        assert rep["summary"]["results"] == 1 and len(rep["frames_done"]) == 1
        assert rep["normalisation"] == doc["normalisation"]  # how the frames were corrected
        assert rep["options"]["checks"] == {"collapse_ratio": 0.6, "motion_limit": 6.0,
                                            "motion_floor": [1.0, 2.0], "sigma_limit": 3.0}  # the defaults
        assert rep["options"]["trajectory_limit"] == 2.5 and rep["options"]["backward_limit"] == 1.25
    journal = demo / "results" / "walk" / "poses" / "talus.jsonl"
    before = journal.read_bytes()
    rc = main([str(demo), "--trial", "walk", "--bones", "talus", "--frames", "1:2", "--device", "cpu",
               "--resume", "--quiet"])
    doc = json.loads(capsys.readouterr().out)
    assert rc == 0 and doc["summary"]["results"] == 1  # the report keeps the earlier frame
    assert journal.read_bytes() == before  # nothing left to do: nothing re-tracked


def test_track_command_bad_input(demo, capsys):
    assert main([str(demo), "--trial", "nope"]) == 1
    assert "nope" in capsys.readouterr().err
    assert main([str(demo), "--trial", "walk", "--bones", "talus", "--frames", "0:1", "--device", "cpu",
                 "--threshold", "99999", "--quiet"]) == EXIT_NOTHING_DONE  # no bone above the threshold
    doc = json.loads(capsys.readouterr().out)
    assert "threshold" in doc["stopped"]["talus"]
    assert main([str(demo / "missing"), "--trial", "walk"]) == 1
    capsys.readouterr()
    for bad in ("0.3", "a,b", "0.3,-1"):
        args = [str(demo), "--trial", "walk", "--frames", "0:1", "--max-uncertainty", bad, "--quiet"]
        assert main(args) == 1
        assert "max_uncertainty" in capsys.readouterr().err.replace("-", "_")


def test_final_likelihood_is_refused_on_frames_without_flatfield(demo, capsys):
    """The demo's frames are divided by the full scale: --final likelihood names the trial, exit 1,
    before any tracking."""
    journal = demo / "results" / "walk" / "poses" / "talus.jsonl"
    before = journal.read_bytes() if journal.exists() else None
    rc = main([str(demo), "--trial", "walk", "--bones", "talus", "--frames", "1:2", "--device", "cpu",
               "--final", "likelihood", "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1
    assert "--final likelihood: trial 'walk'" in err and "not flatfield-corrected" in err
    assert (journal.read_bytes() if journal.exists() else None) == before  # nothing tracked


def test_final_reaches_the_tracking_options(demo, capsys, monkeypatch):
    """--final likelihood sets TrackingOptions.refine_likelihood (the registrations' final stage);
    without it the options are those the command always built. The tracker is not run."""
    import core.tracking.from_study as from_study
    from app.commands import track
    from core.tracking.register import RegistrationOptions
    from core.tracking.results import FrameResult
    from core.tracking.trial import TrackingOptions

    seen = []

    def fake_track_study(study, trial, bones, frames, *, options, progress, **kw):
        seen.append(options)
        if options.refine_likelihood:  # one bone-frame refined, one left at the similarity's pose, one
            # whose move the move check rejected
            for k, (taken, rej) in enumerate(((1, 0), (0, 0), (0, 1))):
                timing = {"likelihood_taken": taken, "likelihood_rejected": rej}
                progress(k + 1, 3, FrameResult("talus", k, np.eye(4), 0.9, 10, 0.1, True, timing=timing))
        return None, {"summary": {"status": "stopped"}}

    monkeypatch.setattr(from_study, "track_study", fake_track_study)
    monkeypatch.setattr(track, "final_stage_problem", lambda study, trial: None)  # as a flatfield trial
    args = [str(demo), "--trial", "walk", "--frames", "0:1", "--quiet", "--search", "newton", "--scale", "2",
            "--metric", "components", "--guess", "spline", "--max-uncertainty", "0.3,0.6"]
    assert main(args) == EXIT_NOTHING_DONE
    assert "final_stage" not in json.loads(capsys.readouterr().out)
    assert main([*args, "--final", "likelihood"]) == EXIT_NOTHING_DONE
    out = capsys.readouterr()
    assert json.loads(out.out)["final_stage"] == {"method": "likelihood", "bone_frames": 3, "refined": 1,
                                                  "rejected": 1}
    assert "kept in 1 of 3 bone-frames" in out.err and "the move check rejected it in 1" in out.err
    plain, final = seen
    reg = RegistrationOptions(terms=track.registration_terms("components"), bounds=(5.0, 5.0),
                              sigma=(1.0, 1.0), search="newton", final_scale=2.0)
    assert plain == TrackingOptions(registration=reg, guess="spline", mode="auto", confidence=True,
                                    max_uncertainty=(0.3, 0.6))  # as the command built them before --final
    assert plain.registration.final is None and not plain.refine_likelihood
    assert final.refine_likelihood and final.registration.final == "likelihood"
    assert final.first_options.final == "likelihood"
    assert track.choices_of(final) == {**track.choices_of(plain), "final": "likelihood"}


def test_ctrl_c_during_the_last_frame_exits_130_and_never_reports_complete(demo, tmp_path):
    """A real ``talus track`` process gets SIGINT while it registers its last frame."""
    import shutil
    import signal
    import subprocess
    import sys
    from pathlib import Path

    from core.study import Study

    study = Path(shutil.copytree(demo, tmp_path / "study"))
    cmd = [sys.executable, "-m", "app.cli", "track", str(study), "--trial", "walk", "--bones",
           "talus", "--frames", "1:3", "--device", "cpu", "--no-confidence", "--scale", "2"]
    root = Path(__file__).resolve().parents[2]
    proc = subprocess.Popen(cmd, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    err = []
    try:
        for line in proc.stderr:  # wait for the event: frame 1 of 2 done, frame 2 in flight
            err.append(line)
            if "1/2" in line:
                proc.send_signal(signal.SIGINT)
                break
        out, rest = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
    err = "".join(err) + rest
    assert any("1/2" in ln for ln in err.splitlines()), err
    assert proc.returncode == 130, err
    doc = json.loads(out)
    assert doc["summary"]["status"] == "cancelled"
    assert "complete" not in out and "complete" not in rest.replace("completed", "")
    assert "Traceback" not in err and "cancelled" in err
    with Study.open(study) as st:
        P = st.trial("walk").poses("talus")
    assert np.all(np.isfinite(P[1]))  # the finished frame is saved
    assert np.all(np.isnan(P[2]))  # the cancelled one is not: --resume will track it


def test_track_study_itself_refuses_the_final_stage_without_flatfield(demo):
    """Python's track_study makes the same test: the likelihood final stage on frames divided by the
    full scale raises, naming the trial, before any frame is registered."""
    import pytest

    from core.study import Study
    from core.tracking.from_study import final_stage_problem, track_study
    from core.tracking.options import TrackingOptions

    with Study.open(demo, mode="w") as study:
        assert "'walk'" in final_stage_problem(study, "walk")
        with pytest.raises(ValueError, match=r"'walk'.*not flatfield-corrected"):
            track_study(study, "walk", ["talus"], [1], options=TrackingOptions(refine_likelihood=True),
                        device="cpu")

"""talus batch --smooth: once the batch has run, each trial whose tasks all complete has its bones'
poses smoothed over the trial (as talus track --smooth) into results/reports/smoothing/<trial>.json;
a trial with a task not complete is not smoothed; off by default. The batch's tasks are a stand-in
recording noisy true poses with a confidence σ (nothing registered)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.study import Study
from tests.app._helpers import parse_command, run_command

N = 10
SIGMA = [0.05, 0.05, 0.05, 0.2, 0.2, 0.2]
REPORT = Path("results") / "reports" / "smoothing" / "walk.json"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    from core.synthetic import make_demo_study

    out = tmp_path_factory.mktemp("batch_smooth") / "study"
    make_demo_study(out, n_frames=N, pixels=32, seed=2, device="cpu", spacing=3.0, tissue_spacing=8.0,
                    calibration_session=False)
    return out


def _tasks_record(monkeypatch, status_of=lambda key: "complete"):
    """``run_serial`` replaced: each task's bones get their true poses moved by noise, with a σ, and
    the task the status ``status_of(key)`` says."""
    import core.tracking.batch as core_batch
    from core.tracking.bones import bone_model

    def run_serial(tasks, settings=None, *, progress=None, cancel=None):
        g = np.random.default_rng(0)
        for t in tasks:
            truths = {b: np.load(Path(t.study) / "poses" / f"{b}.npy") for b in t.bones}
            with Study.open(Path(t.study), mode="w") as st:
                tr = st.trial(t.trial)
                for b in t.bones:
                    c = bone_model(st.bone_volume(b), name=b, threshold=200.0, mesh=False).centroid
                    for f in range(N):
                        e = g.normal(size=6) * 0.5 * np.r_[SIGMA[:3], np.radians(SIGMA[3:])]
                        tr.record_pose(b, f, pose_from_params(e, center=c, base=truths[b][f]), score=0.8,
                                       tracking={"flags": [], "converged": True,
                                                 "confidence": {"sigma": SIGMA}})
        recs = [dict(key=t.key, study=t.study, trial=t.trial, bones=list(t.bones), status=status_of(t.key),
                     seconds=0.0) for t in tasks]
        return core_batch.summarize(tasks, recs, [], wall_s=0.1, workers=0)

    monkeypatch.setattr(core_batch, "run_serial", run_serial)


def test_smooth_is_off_by_default():
    from app.commands import batch

    assert parse_command(["S"], batch).smooth is False
    assert parse_command(["S", "--smooth"], batch).smooth is True


def test_batch_smooth_smooths_each_complete_trial(demo, tmp_path, capsys, monkeypatch):
    from app.commands import batch
    from core.tracking.smoothing_trial import smooth_trial

    study = Path(shutil.copytree(demo, tmp_path / "study"))
    _tasks_record(monkeypatch)
    argv = [str(study), "--trials", "walk", "--bones", "talus,calcaneus", "--workers", "0", "--quiet"]
    assert run_command(argv, batch, "batch") == 0  # off by default
    assert "smoothed" not in json.loads(capsys.readouterr().out) and not (study / REPORT).exists()
    assert run_command([*argv, "--smooth"], batch, "batch") == 0
    cap = capsys.readouterr()
    s = json.loads(cap.out)
    assert s["smoothed"] == [{"study": str(study), "trial": "walk", "report": REPORT.as_posix(),
                              "bones": ["calcaneus", "talus"], "skipped": {}}]
    assert f"smoothed poses of calcaneus, talus in {REPORT.as_posix()}" in cap.err
    rep = json.loads((study / REPORT).read_text())
    with Study.open(study) as st:  # the same as talus track --smooth's over those bones
        want = smooth_trial(st, "walk", ["talus", "calcaneus"], write=False)
    assert sorted(rep["bones"]) == ["calcaneus", "talus"]
    for b in rep["bones"]:
        np.testing.assert_allclose(rep["bones"][b]["poses"], want["bones"][b]["poses"], atol=1e-9)


def test_batch_smooth_leaves_a_trial_with_a_task_not_complete(demo, tmp_path, capsys, monkeypatch):
    from app.commands import batch

    study = Path(shutil.copytree(demo, tmp_path / "study"))
    _tasks_record(monkeypatch, lambda key: "stopped" if key.endswith("/calcaneus") else "complete")
    argv = [str(study), "--trials", "walk", "--bones", "talus,calcaneus", "--workers", "0", "--quiet",
            "--smooth"]
    assert run_command(argv, batch, "batch") == 4  # a task had nothing it could track
    cap = capsys.readouterr()
    entry = json.loads(cap.out)["smoothed"][0]
    assert entry["not_smoothed"] == f"1 of 2 tasks not complete ({study.name}/walk/calcaneus)"
    assert f"{study.name}/walk: not smoothed: 1 of 2 tasks not complete" in cap.err
    assert not (study / REPORT).exists()

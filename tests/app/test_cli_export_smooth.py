"""talus export --smooth: the poses of File → Export…'s *Smoothed poses*
(core.tracking.smoothing_trial.smoothed_poses) written in place of the tracked ones, in a pose format
and a trial format; off by default; the journal's poses unchanged."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from app.cli import main as talus
from core.geometry.transforms import pose_from_params
from core.study import Study

N = 10
SIGMA = [0.05, 0.05, 0.05, 0.2, 0.2, 0.2]


@pytest.fixture(scope="module")
def study(tmp_path_factory):
    """A tiny demo study whose bones hold their true poses moved by noise, each with a confidence σ
    (frame 4 flagged), as tracking records them; the last bone only two more beside the demo's
    keyframes (too few to smooth)."""
    from core.synthetic import make_demo_study
    from core.tracking.bones import bone_model

    out = tmp_path_factory.mktemp("export_smooth") / "study"
    make_demo_study(out, n_frames=N, pixels=32, seed=2, device="cpu", spacing=3.0, tissue_spacing=8.0,
                    calibration_session=False)
    truths = {p.stem: np.load(p) for p in (out / "poses").glob("*.npy")}
    g = np.random.default_rng(0)
    with Study.open(out, mode="w") as st:
        tr = st.trial("walk")
        for i, b in enumerate(tr.bones):
            c = bone_model(st.bone_volume(b), name=b, threshold=200.0, mesh=False).centroid
            for f in (range(N) if i < len(tr.bones) - 1 else (3, 4)):
                e = g.normal(size=6) * 0.5 * np.r_[SIGMA[:3], np.radians(SIGMA[3:])]
                tr.record_pose(b, f, pose_from_params(e, center=c, base=truths[b][f]), score=0.8,
                               tracking={"flags": ["off the trajectory"] if f == 4 else [], "converged": True,
                                         "confidence": {"sigma": SIGMA}})
    return out


def _csv_poses(path, k):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))[1:]
    return np.array([[[float(v or "nan") for v in r[1 + 16 * j:17 + 16 * j]] for j in range(k)] for r in rows]
                    ).reshape(-1, k, 4, 4)


def test_parser_takes_smooth_off_by_default():
    from app.cli import build_parser

    p = build_parser()
    a = p.parse_args(["export", "S", "--trial", "walk", "--format", "csv"])
    assert a.smooth is False and a.threshold == 200.0
    a = p.parse_args(["export", "S", "--trial", "walk", "--format", "csv", "--smooth", "--threshold", "300"])
    assert a.smooth is True and a.threshold == 300.0


def test_export_smooth_writes_the_dialogs_smoothed_poses(study, tmp_path, capsys):
    from core.tracking.smoothing_trial import smoothed_poses

    with Study.open(study) as st:
        bones = list(st.trial("walk").bones)
        tracked = np.stack([st.trial("walk").poses(b) for b in bones], axis=1)
        want = smoothed_poses(st, "walk", bones)
    short = bones[-1]
    assert talus(["export", str(study), "--trial", "walk", "--format", "csv",
                  "--out", str(tmp_path / "raw.csv")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert "smoothed" not in out and 2 <= out["frames_with_pose"][short] < 5  # the demo's keyframe too
    assert talus(["export", str(study), "--trial", "walk", "--format", "csv", "--smooth",
                  "--out", str(tmp_path / "sm.csv")]) == 0
    cap = capsys.readouterr()
    out = json.loads(cap.out)
    assert out["smoothed"] is True
    assert f"{short} has too few poses to smooth" in cap.err
    assert out["frames_with_pose"] == {b: (0 if b == short else N) for b in bones}
    raw, sm = _csv_poses(tmp_path / "raw.csv", len(bones)), _csv_poses(tmp_path / "sm.csv", len(bones))
    np.testing.assert_allclose(raw, tracked, atol=1e-9)  # off by default: the tracked poses
    np.testing.assert_allclose(sm, np.stack([want[b] for b in bones], axis=1), atol=1e-9)
    assert not np.allclose(sm[:, 0], raw[:, 0])
    with Study.open(study) as st:  # the journal keeps the tracked poses
        np.testing.assert_array_equal(np.stack([st.trial("walk").poses(b) for b in bones], axis=1), tracked)
    # a trial format (export_trial) takes them too, a bone named
    assert talus(["export", str(study), "--trial", "walk", "--format", "xromm-csv", "--smooth",
                  "--bones", bones[0], "--out", str(tmp_path / "sm_xromm.csv")]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["smoothed"] is True and out["frames_with_pose"] == {bones[0]: N}
    assert (tmp_path / "sm_xromm.csv").is_file()


def test_export_smooth_refuses_a_misspelt_bone(study, tmp_path, capsys):
    assert talus(["export", str(study), "--trial", "walk", "--format", "csv", "--smooth", "--bones", "tlaus",
                  "--out", str(tmp_path / "x.csv")]) == 1
    assert "no bone 'tlaus'" in capsys.readouterr().err

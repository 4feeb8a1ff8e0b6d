"""The failure checks' thresholds as TrackingOptions fields: defaults, their effect, validation."""

from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.tracking import checks
from core.tracking.attempt import _conf_flags
from core.tracking.checks import failures
from core.tracking.options import CHECK_FIELDS, TrackingOptions

O = TrackingOptions()
C = np.array([10.0, -5.0, 30.0])


def _pose(p):
    return pose_from_params(np.r_[p[:3], np.radians(p[3:])], center=C, base=np.eye(4))


def _res(pose, score=0.5):
    return SimpleNamespace(score=score, converged=True, reason="", pose=pose)


def test_the_defaults_are_the_module_constants():
    assert set(CHECK_FIELDS) == {"collapse_ratio", "motion_limit", "motion_floor", "sigma_limit"}
    assert (O.collapse_ratio, O.motion_limit, O.motion_floor, O.sigma_limit) == (
        checks.COLLAPSE_RATIO, checks.MOTION_LIMIT, checks.MOTION_FLOOR, checks.SIGMA_LIMIT)
    # given as a list or as integers, the same options
    assert replace(O, motion_floor=[1, 2]) == O and replace(O, motion_floor=[1, 2]).motion_floor == (1.0, 2.0)


def test_collapse_ratio_sets_the_score_collapse():
    scores = [0.5] * 10
    kw = {"start_score": 0.5}
    assert any(f.startswith("score collapse")
               for f in failures(_res(np.eye(4), 0.28), np.eye(4), C, scores, O, **kw))  # < 0.6 x 0.5
    lenient = replace(O, collapse_ratio=0.5)
    f = failures(_res(np.eye(4), 0.28), np.eye(4), C, scores, lenient, **kw)
    assert f and not any(x.startswith("score collapse") for x in f)  # a score drop only: confirmable
    strict = replace(O, collapse_ratio=0.8)
    f = failures(_res(np.eye(4), 0.38), np.eye(4), C, scores, strict, **kw)
    assert any(x.startswith("score collapse (0.380 < 0.8 x") for x in f), f


def test_motion_limit_and_floor_set_the_unexpected_motion_flag():
    hist = [(f, _pose(np.array([0.8 * f, 0.0, 0.0, 0.6 * f, 0.0, 0.0]))) for f in range(12)]
    pred = _pose(np.array([0.8 * 12, 0.0, 0.0, 7.2, 0.0, 0.0]))
    off = pred.copy()
    off[0, 3] += 1.5  # 1.5 mm off an exact track: past the 1 mm floor
    kw = {"start_score": 0.5, "history": hist, "frame": 12}
    assert any(x.startswith("unexpected motion") for x in failures(_res(off), pred, C, [0.5] * 12, O, **kw))
    wide = replace(O, motion_floor=(2.0, 2.0))
    assert failures(_res(off), pred, C, [0.5] * 12, wide, **kw) == []
    # a noisy track: the limit is motion_limit x the median miss
    g = np.random.default_rng(1)
    noisy = [(f, _pose(np.array([0.8 * f, 0.0, 0.0, 0.6 * f, 0.0, 0.0]) + g.normal(scale=0.3, size=6)))
             for f in range(12)]
    got = checks.motion_miss(pred, noisy, 12, C)
    assert got is not None and got[2] > O.motion_floor[0]  # the noise, not the floor, sets it
    loose = checks.motion_miss(pred, noisy, 12, C, limit=2 * O.motion_limit)
    assert loose[2] == pytest.approx(2 * got[2])
    o2 = replace(O, motion_limit=2 * O.motion_limit)
    far = pred.copy()
    far[0, 3] += 1.5 * got[2]  # between the two limits
    kw["history"] = noisy

    def motion(o):
        f = failures(_res(far), pred, C, [0.5] * 12, o, **kw)
        return [x for x in f if x.startswith("unexpected motion")]

    assert motion(O) and not motion(o2)


def test_sigma_limit_reaches_the_relative_uncertain_flag():
    good = [(0.15, 0.9)] * 8
    conf = {"translation_mm": 0.2, "rotation_deg": 2.0, "well_posed": True}  # 2.2x the median rotation
    assert _conf_flags(conf, [], O, good) == []
    f = _conf_flags(conf, [], replace(O, sigma_limit=2.0), good)
    assert len(f) == 1 and f[0].startswith("uncertain") and "over 2 x" in f[0], f


@pytest.mark.parametrize(("field", "value", "expected"), [
    ("collapse_ratio", 1.5, r"collapse_ratio: expected a ratio in \[0, 1\]"),
    ("collapse_ratio", -0.1, r"collapse_ratio: expected a ratio in \[0, 1\]"),
    ("collapse_ratio", float("nan"), "collapse_ratio: expected a finite number"),
    ("motion_limit", 0.5, "motion_limit: expected a factor >= 1"),
    ("motion_limit", float("inf"), "motion_limit: expected a finite number"),
    ("sigma_limit", 0.9, "sigma_limit: expected a factor >= 1"),
    ("sigma_limit", "3", "sigma_limit: expected a finite number"),
    ("motion_floor", (1.0,), r"motion_floor: expected \(mm, degrees\)"),
    ("motion_floor", (1.0, -2.0), r"motion_floor: expected \(mm, degrees\)"),
    ("motion_floor", 1.0, r"motion_floor: expected \(mm, degrees\)"),
])
def test_bad_thresholds_are_refused_naming_the_option_and_its_range(field, value, expected):
    with pytest.raises(ValueError, match=expected):
        TrackingOptions(**{field: value})

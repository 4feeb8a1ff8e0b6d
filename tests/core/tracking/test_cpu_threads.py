"""The engine's metric launches split over CPU threads give the results of one thread, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.tracking.cost import DEFAULT_TERMS, MetricTerm, prepare_frame, search_roi
from core.tracking.cpu_threads import split_cpu_launches
from core.tracking.engine import GaussNewtonCost, step_design

H = np.array([0.25] * 3 + [0.5] * 3)


@pytest.mark.parametrize("term", [DEFAULT_TERMS[0], MetricTerm("ncc", 1.0, {})])
def test_split_metric_equals_one_thread(talus_scene, term):
    sc = talus_scene
    r, m = sc["renderer"], sc["model"]
    frame = prepare_frame(sc["fluence"](2))
    truth = sc["scene"].poses(2)[0]
    x = np.r_[0.8, -0.5, 0.4, np.radians([1.0, -0.5, 0.8])]
    start = pose_from_params(x, center=m.centroid, base=truth)
    roi = search_roi(r, start, 0, views=(0, 1), center=m.centroid, reach_mm=7.6, points=m.outline)
    threads0 = r.cpu_threads
    r.cpu_threads = 1  # the engine records its launches unsplit
    try:
        gn = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=term)
        gn.set_frame(frame, base_pose=start, center=m.centroid, roi=roi)
        _compare(gn)
    finally:
        r.cpu_threads = threads0
    r.cpu_threads = 2  # the engine's own pipelines split on two threads: the same values
    try:
        gn2 = GaussNewtonCost(r, bone=0, views=(0, 1), scale=1.0, term=term)
        gn2.set_frame(frame, base_pose=start, center=m.centroid, roi=roi)
        e2 = gn2._evaluate(step_design(np.zeros(6), H))
        assert len(gn2._pipes[13].launches) < len(gn._pipes[13].launches)
        e1 = gn._evaluate(step_design(np.zeros(6), H))
        for a1, a2 in zip(e1, e2, strict=True):
            assert (a1 is None and a2 is None) or np.array_equal(np.asarray(a1), np.asarray(a2),
                                                                 equal_nan=True)
    finally:
        r.cpu_threads = threads0


def _compare(gn):
    for B in (13, 1):
        gn._evaluate(step_design(np.zeros(6), H)[:B])  # renders the DRRs, builds the pipeline
        pipe = gn._pipes[B]
        one = pipe.launches
        out1, gn1 = pipe.run()
        for threads in (2, 3):
            pipe.launches = split_cpu_launches(one, threads)
            try:
                out2, gn2 = pipe.run()
            finally:
                pipe.launches = one
            assert np.array_equal(out1, out2, equal_nan=True)
            if B == 13:
                assert np.array_equal(gn1, gn2)
            else:
                assert gn1 is None and gn2 is None
        if B == 13:  # 26 items over 2 views: the blur passes and the statistics were split
            steps = split_cpu_launches(one, 2)
            assert len(steps) < len(one)
            assert sum(len(getattr(s, "cmds", [s])) for s in steps) > len(steps)
    assert split_cpu_launches(one, 1) == one

"""The CPU frame-time study: one and two DRR threads track to the same poses."""

from __future__ import annotations

import pytest


def test_cpu_frames_smoke():
    from core.studies.tracking.cpu_frames import run

    # 128² views: the Gauss-Newton search converges in about 80 evaluations per frame (0.16 s of
    # CPU); at 64² every frame failed its checks and was retried (2,000-2,600 evaluations, 1.6-2.7
    # s), and the whole study cost 15-20 s of CPU against 5 s
    res = run(frames=3, pixels=128, voxel=1.0, threads=(1, 2), rounds=1, first=False, bound_frames=1)
    st = res["steady"]
    assert st["same_poses"] is True
    assert [x["threads"] for x in st["runs"]] == [1, 2]
    for run_ in st["runs"]:
        assert run_["frames"] == [1, 2]  # frame 0 is given
        assert all(x["cpu_s"] >= 0 and x["wall_s"] > 0 and x["load_1min"] >= 0 for x in run_["per_frame"])
    assert st["threads_2"]["rms_error_mm"] == pytest.approx(st["threads_1"]["rms_error_mm"])
    assert "whole" not in res
    with pytest.raises(ValueError, match="frames"):
        run(frames=1)

"""core.studies.tracking.concurrent_runs on Warp's CPU device at a small size: two trackings at once in two
threads (renderers, engines and buffers of their own; the CMA-ES searches' global random state and the CPU's
tile kernels serialized, the study's default) give the poses the same two give one after the other, to the
bit: the tracker's memos and per-thread state (the search's workspace, the shared upload, the pyramid
made ahead, the recorded launches) do not leak between concurrent runs (two frames: the first frame's
global search and one tracked frame)."""

from __future__ import annotations


def test_concurrent_runs_agree_on_the_cpu():
    from core.studies.tracking.concurrent_runs import run

    rec = run("cpu", 2, 40, 4.0)
    assert rec["serialized"] == ["cmaes", "cpu_launches"]
    assert rec["sequential_floor"]["frames_differ"] == 0
    for k in ("a", "b"):
        got = rec["concurrent"][k]
        assert got["error"] is None and got["vs_sequential"]["frames_differ"] == 0, got
        assert got["vs_sequential"]["flags_differ"] == 0, got
    assert rec["after_concurrent"]["likelihood_segments.FAILED"] is None

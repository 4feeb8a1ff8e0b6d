"""The stage studies' host breakdowns (core.studies.tracking.stage_one_bone's ``_HOST``, stage_speed's
``_PARTS``) time the engine's methods by name: every name is one the engine has, and the stage's default
path — the robust round as one piece (``robust_scale``) and, on the recorded set-up's path, the neighbours'
DRRs through the engine's own item table (``_others_own``) — is timed, so the breakdowns stay whole."""

from __future__ import annotations

import importlib

from tests.core.tracking.stage_helpers import stage_calls


def test_every_name_timed_is_the_engines():
    from core.studies.tracking.stage_one_bone import _HOST
    from core.studies.tracking.stage_speed import _PARTS
    from core.tracking.engine_likelihood import LikelihoodEngine

    for mod, owner, name in _HOST:
        obj = importlib.import_module(mod)
        obj = obj if owner is None else getattr(obj, owner)
        assert callable(getattr(obj, name)), (mod, owner, name)
    for name in _PARTS:
        assert callable(getattr(LikelihoodEngine, name)), name


def test_the_default_paths_pieces_are_timed(talus_calcaneus_128, monkeypatch):
    """Both bones' stages side by side with the other subtracted, the recorded set-up's path (the
    pieces and the recorded step on, as on a CUDA device): robust_scale and _others_own among the parts
    timed with calls, in both studies' breakdowns."""
    import core.tracking.engine_likelihood as el
    import core.tracking.likelihood_segments as seg
    from core.studies.tracking.stage_one_bone import _host_parts
    from core.studies.tracking.stage_speed import _parts_profile
    from core.tracking.final_stage import final_stages

    monkeypatch.setattr(el, "STEP_GRAPH", True)
    monkeypatch.setattr(seg, "SEGMENT_GRAPHS", True)
    monkeypatch.setattr(seg, "FAILED", None)
    r, frame, calls, _ = stage_calls(talus_calcaneus_128)
    host: dict = {}
    with _host_parts(host):
        final_stages(r, frame, calls)
    for name in ("set_frame", "_others_own", "robust_scale", "sandwich_launch"):
        assert host.get(name, [0.0, 0])[1] >= 2, (name, sorted(host))
    assert "_frame_others" not in host  # (not on this path: its host part is _others_own's)
    parts: dict = {}
    with _parts_profile(parts):
        final_stages(r, frame, calls)
    assert parts.get("robust_scale", [0.0, 0])[1] >= 2, sorted(parts)
    # (outside the blocks the engine's methods are its own again)
    assert el.LikelihoodEngine.robust_scale.__qualname__.endswith("_RegionWeights.robust_scale")

"""The frame profile study's wrappers (core.studies.tracking.frame_profile): per phase the frame step's
calls and its parts timed, the joint pipeline still taken under them, and every wrapped function
restored after the block (ideal 128² talus-calcaneus, CPU device)."""

from __future__ import annotations


def test_profile_run_phases_and_restores(talus_calcaneus_128):
    import importlib

    import core.tracking.final_stage as fst
    import core.tracking.trial as trial
    from core.studies.tracking.frame_profile import WRAPPED, profile_run
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    def current():
        got = {}
        for modname, names in WRAPPED:
            mod = importlib.import_module(modname)
            for name in names:
                obj, _, attr = name.rpartition(".")
                owner = getattr(mod, obj) if obj else mod
                got[(modname, name)] = getattr(owner, attr, None)
        return got, trial.track_frame, fst.final_stage_steps

    before = current()
    sc, models, r, imgs = talus_calcaneus_128
    keys = {m.name: {0: sc.poses(0)[k]} for k, m in enumerate(models)}
    reg = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    o = TrackingOptions(mode="joint", verify_restarts=0, registration=reg, refine_likelihood=True)
    got = profile_run(r, models, imgs.__getitem__, [0, 1], keys, o, skip=keys)  # frame 0 given: frame 1 alone
    assert current() == before
    stats = got["stats"]
    rows = {ph: {x["name"]: x for x in stats[ph]} for ph in stats}
    assert "later" not in stats and rows["first"]["track_frame"]["calls"] == 1  # (the run's first frame step)
    assert rows["first"]["joint_pipeline.run_pipelined"]["calls"] == 1  # (applies() sees final_stages)
    assert rows["first"]["stage_gen.next0"]["calls"] == 2
    assert rows["first"]["engine_upload.share"]["calls"] >= 1 and rows["first"]["engine.stage"]["calls"] >= 2
    for ph in stats:
        for x in stats[ph]:
            assert 0 <= x["excl_ms"] <= x["incl_ms"] + 1e-9
    assert got["wall_s"] > 0 and got["ms_per_frame_after_first"] > 0
    assert set(got["gc"]) == {"collections", "pause_ms", "pause_ms_total"}
    assert "after_last_frame_ms" in got["frames"]


def test_variants_parsed_and_switched():
    """``--variants``: each name's switches (modules under core.tracking, literal values), set within the
    block and put back after."""
    import core.tracking.register as reg
    import core.tracking.trial as trial
    from core.studies.tracking.frame_profile import parse_variants, switched

    v = parse_variants("base:register.SHARE_FRAME=False,trial.NEXT_FRAME_AHEAD=0; on:")
    assert v == {"base": [("core.tracking.register", "SHARE_FRAME", False),
                          ("core.tracking.trial", "NEXT_FRAME_AHEAD", 0)], "on": []}
    was = (reg.SHARE_FRAME, trial.NEXT_FRAME_AHEAD)
    with switched(v["base"]):
        assert (reg.SHARE_FRAME, trial.NEXT_FRAME_AHEAD) == (False, 0)
    assert (reg.SHARE_FRAME, trial.NEXT_FRAME_AHEAD) == was


def test_frame_walls():
    """Each frame after the first timed from the end of the one before; the run after its last frame apart."""
    from core.studies.tracking.frame_profile import frame_walls

    got = frame_walls({3: 1.0, 4: 1.002, 5: 1.012, 6: 1.015}, [3, 4, 5, 6], 0.9, 0.125)
    assert abs(got["median_ms"] - 3.0) < 1e-6 and abs(got["max_ms"] - 10.0) < 1e-6
    assert abs(got["mean_ms"] - 5.0) < 1e-6 and got["slowest"][0][0] == 5
    assert abs(got["after_last_frame_ms"] - 10.0) < 1e-6
    assert frame_walls({}, [1, 2], 0.0, 1.0) == {}


def test_rounds_rotate_the_variants_order():
    """Round ``i`` starts with the ``i``-th variant, so no variant always runs first (a position bias)."""
    from core.studies.tracking.frame_profile import rotated

    names = ["base", "a", "b"]
    assert [rotated(names, i) for i in range(4)] == [["base", "a", "b"], ["a", "b", "base"],
                                                     ["b", "base", "a"], ["base", "a", "b"]]
    assert rotated([], 2) == []


def test_unusual_calls_of_a_slow_frame():
    """What a frame's step called that the median frame after the first did not (or more often)."""
    from core.studies.tracking.frame_profile import _Stats

    st = _Stats()
    st.first = 0
    st.per_frame = {0: {"register._run": [1, 0.02]},
                    **{f: {"attempt.register": [1, 0.004], "engine.stage": [1, 0.0005]} for f in range(1, 9)}}
    st.per_frame[6] = {"attempt.register": [2, 0.009], "engine.stage": [2, 0.001],
                       "stage_sigma.remeasured": [1, 0.004]}
    got = st.unusual([6, 3])
    assert got[3] == []
    assert [r[0] for r in got[6]] == ["attempt.register", "stage_sigma.remeasured", "engine.stage"]
    assert got[6][1][1:3] == [1, 0.0] and abs(got[6][0][3] - 9.0) < 1e-9

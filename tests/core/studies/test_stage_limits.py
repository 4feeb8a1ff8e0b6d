"""stage_limits: the bias / spread decomposition of a bone's errors, the variants' settings, and
the study probes put back after their block."""

import numpy as np
import pytest

from core.studies.tracking import stage_limits as sl


def test_bone_stats_splits_the_rms_into_bias_and_spread():
    g = np.random.default_rng(0)
    E = g.normal(size=(400, 6)) * [0.01, 0.01, 0.01, 0.1, 0.1, 0.1] + [0.03, 0.0, -0.04, 0.0, 0.2, 0.0]
    E[5] = np.nan
    s = sl.bone_stats(E, {"rms_mm": 0.05, "rms_deg": 0.2})
    assert s["n"] == 399 and s["missing"] == 1
    assert s["rms_mm"] ** 2 == pytest.approx(s["bias_mm"] ** 2 + s["spread_mm"] ** 2, rel=1e-9)
    assert s["rms_deg"] ** 2 == pytest.approx(s["bias_deg"] ** 2 + s["spread_deg"] ** 2, rel=1e-9)
    assert s["bias_mm"] == pytest.approx(0.05, abs=0.002)
    assert s["mean_error"][4] == pytest.approx(0.2, abs=0.02)
    assert s["rms_over_bound"][0] == pytest.approx(s["rms_mm"] / 0.05, abs=1e-3)
    assert all(abs(a) < 0.15 for a in s["lag1_autocorrelation"])  # independent frames
    assert "rms_over_bound" not in sl.bone_stats(E)


def test_variants_join_and_refuse_unknown_parts():
    assert sl.variant("default") == {}
    assert sl.variant("true+hp6+plain") == {"frames": "true", "hp": 6.0, "robust": None}
    with pytest.raises(ValueError, match="unknown part"):
        sl.variant("hp5")


def test_variant_block_sets_the_model_and_puts_the_probes_back():
    import core.tracking.final_stage as fst
    from core.tracking.engine_likelihood import LikelihoodEngine

    before = (fst.MODEL, fst.likelihood_engine, LikelihoodEngine.set_frame)
    v = sl.Variant(sl.variant("hp6+huber+noothers"))
    assert v.options.refine_likelihood and v.options.registration.final_highpass_px == 6.0
    assert v.options.registration.search == "newton" and v.options.mode == "joint"
    with v:
        assert fst.MODEL.robust_kind == "huber"
        assert LikelihoodEngine.set_frame is not before[2]
    assert (fst.MODEL, fst.likelihood_engine, LikelihoodEngine.set_frame) == before
    assert not sl.Variant({"stage": False}).options.refine_likelihood

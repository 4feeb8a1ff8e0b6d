"""Per-bone settings of the likelihood final stage (core.tracking.final_stage.FinalModel.bones): a
bone's high-pass σ and its tissue regressor turned off, each giving the same result as the model
or options that say so for every bone; the defaults unchanged."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from core.geometry.transforms import pose_from_params
from core.tracking.cost import prepare_frame
from core.tracking.final_stage import MODEL, BoneStage, FinalModel, final_model


def test_bone_stage_validation_and_serialisation():
    for kw, msg in (({"highpass_px": -1.0}, "highpass_px"), ({"highpass_px": np.nan}, "highpass_px"),
                    ({"tissue": "no"}, "tissue")):
        with pytest.raises(ValueError, match=msg):
            BoneStage(**kw)
    with pytest.raises(ValueError, match="bones"):
        FinalModel(bones={-1: BoneStage()})
    with pytest.raises(ValueError, match="bones"):
        FinalModel(bones={0: 3.0})
    assert FinalModel().bones == () and "bones" not in FinalModel().to_dict()
    assert MODEL.for_bone(2, 4.0) == (MODEL, 4.0)
    m = FinalModel(bones={2: {"highpass_px": 8}, 0: BoneStage(tissue=False)})
    assert m.bones == ((0, BoneStage(tissue=False)), (2, BoneStage(highpass_px=8.0)))
    assert m == FinalModel(bones=((2, BoneStage(highpass_px=8.0)), (0, BoneStage(tissue=False))))
    assert m.to_dict()["bones"] == {"0": {"highpass_px": None, "tissue": False},
                                    "2": {"highpass_px": 8.0, "tissue": True}}
    assert FinalModel(bones=m.to_dict()["bones"]) == m  # the record reads back
    assert m.for_bone(2, 4.0) == (m, 8.0) and m.for_bone(1, 4.0) == (m, 4.0)
    assert m.for_bone(0, 4.0) == (m, 4.0)  # (no tissue to turn off)
    t = replace(m, tissue=((_blob(None), 1),))
    assert t.for_bone(0, 4.0) == (replace(t, tissue=()), 4.0) and t.for_bone(1, 4.0) == (t, 4.0)


def _blob(model):
    from core.render import CTVolume

    n, sp = 12, 5.0
    k, j, i = np.indices((n, n, n)) - (n - 1) / 2
    rr = np.sqrt((i / 5.0) ** 2 + (j / 4.0) ** 2 + (k / 5.0) ** 2)
    mu = (0.02 / (1 + np.exp((rr - 1.0) * 8))).astype(np.float32)
    c = np.zeros(3) if model is None else np.asarray(model.centroid)
    corner = c + np.array([6.0, -4.0, 3.0]) - sp * (n - 1) / 2
    return CTVolume(mu, spacing=np.full(3, sp), origin=corner, units="1/mm", name="blob")


def test_per_bone_high_pass_and_tissue_equal_the_models_that_say_so(talus_scene):
    from core.tracking.engine_likelihood import likelihood_engine
    from core.tracking.final_stage import final_stage, tissue_renderer
    from core.tracking.register import RegistrationOptions, register

    sc, model, r = talus_scene["scene"], talus_scene["model"], talus_scene["renderer"]
    f = 3
    truth = sc.poses(f)[0]
    vol = _blob(model)
    tr = tissue_renderer(r, ((vol, 0),))
    Lt = tr.render(truth[None, None], roi="full").numpy()[0, :, 0]
    fr = prepare_frame([fl * np.exp(-np.nan_to_num(t)) for fl, t in zip(talus_scene["fluence"](f), Lt,
                                                                             strict=True)], valid_range=None)
    start = pose_from_params(np.r_[0.3, -0.2, 0.2, np.radians([0.4, -0.3, 0.2])], center=model.centroid,
                             base=truth)
    o = RegistrationOptions(bounds=(3.0, 3.0), search="newton", final_highpass_px=2.0)
    sim = register(r, fr, bone=0, initial_pose=start, center=model.centroid, options=o)  # (no stage)
    o = replace(o, final="likelihood")

    def run(m, opts=o):
        with final_model(m):
            res = final_stage(r, fr, sim, bone=0, initial_pose=start, center=model.centroid, options=opts,
                              views=(0, 1))
        assert res.timing["likelihood_taken"] == 1
        return res

    tissue = FinalModel(tissue=((vol, 0),))
    # the bone's high-pass σ: the options' 3 px for every bone
    a = run(FinalModel(bones={0: BoneStage(highpass_px=3.0)}))
    b = run(FinalModel(), replace(o, final_highpass_px=3.0))
    assert np.array_equal(a.pose, b.pose) and np.array_equal(a.fit.covariance, b.fit.covariance)
    # the bone's tissue off: the model without tissue, to the bit
    c = run(replace(tissue, bones={0: BoneStage(tissue=False)}))
    assert likelihood_engine(r, bone=0, views=(0, 1), highpass_px=2.0)._q == 0
    d = run(FinalModel())
    assert np.array_equal(c.pose, d.pose) and np.array_equal(c.fit.covariance, d.fit.covariance)

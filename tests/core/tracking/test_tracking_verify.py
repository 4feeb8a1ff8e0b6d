"""The restart check (core.tracking.verify) with the Gauss-Newton restarts, on ideal 128² views of
the talus (CPU device): a start off the optimum is corrected, the optimum is confirmed."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from core.geometry.transforms import params_from_pose, pose_from_params


def test_newton_restarts_correct_a_start_off_the_optimum_and_confirm_the_optimum(talus_scene):
    from core.tracking.cost import RegistrationCost, prepare_frame, search_roi
    from core.tracking.register import RegistrationOptions, register
    from core.tracking.verify import verify_start

    s = talus_scene
    sc, m, r = s["scene"], s["model"], s["renderer"]
    truth = sc.poses(2)[0]
    frame = prepare_frame(s["fluence"](2))
    o = RegistrationOptions(bounds=(5.0, 5.0), sigma=(1.0, 1.0), search="newton")
    good = register(r, frame, bone=0, initial_pose=truth, center=m.centroid, options=o, outline=m.outline)
    assert good.converged
    off = pose_from_params(np.r_[2.0, -1.5, 1.0, np.radians([2.0, -1.5, 2.0])], center=m.centroid, base=truth)
    # a result left 2.7 mm / 3.2 deg away, scored where it stands
    roi = search_roi(r, off, 0, views=(0, 1), center=m.centroid, reach_mm=4.0, points=m.outline)
    cost = RegistrationCost(r, frame, bone=0, base_pose=off, center=m.centroid, roi=roi, terms=o.terms)
    wrong = SimpleNamespace(pose=off, score=cost.score(np.zeros(6)))
    assert wrong.score < good.score - 0.01
    chk = verify_start(r, frame, bone=0, result=wrong, center=m.centroid, options=o, n=2, seed=1,
                       outline=m.outline)
    assert chk.improved and len(chk.scores) == 2 and chk.evaluations > 0
    e = params_from_pose(chk.result.pose, center=m.centroid, base=truth)
    assert np.linalg.norm(e[:3]) < 0.3 and np.degrees(np.linalg.norm(e[3:])) < 0.6, e
    ok = verify_start(r, frame, bone=0, result=good, center=m.centroid, options=o, n=2, seed=1,
                      outline=m.outline)
    assert not ok.improved and not ok.ambiguous and ok.result is good

"""The tracking report names the final stage's move-check thresholds whenever the likelihood final
stage runs (core.tracking.from_study)."""

from __future__ import annotations

import shutil

import numpy as np


def test_report_names_the_move_check_of_a_registration_final_stage(demo_walk_48, tmp_path):
    from core.study import Study
    from core.tracking.from_study import track_study
    from core.tracking.register import RegistrationOptions
    from core.tracking.trial import TrackingOptions

    demo = shutil.copytree(demo_walk_48, tmp_path / "demo")
    # the stage set on the registration options (not refine_likelihood): it runs all the same
    opts = TrackingOptions(registration=RegistrationOptions(final="likelihood"), stage_move_limit=5.0)
    with Study.open(demo, mode="w") as st:
        n_views = len(st.trial("walk").rig())
        correction = [lambda raw: np.clip(np.asarray(raw, np.float32) / 65535, 0, 1)] * n_views
        # no bone above the threshold: the report is written before any tracking
        _, rep = track_study(st, "walk", ["talus"], [0], options=opts, device="cpu", threshold_hu=99999,
                             correction=correction)
    assert rep["options"]["stage_move_check"]["stage_move_limit"] == 5.0

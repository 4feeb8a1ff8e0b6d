"""The final stage's parameters of its pose (core.tracking.final_stage.stage_params): those of
core.geometry.transforms.params_from_pose to the bit, without its checks."""

import numpy as np

from core.geometry.transforms import params_from_pose, pose_from_params
from core.tracking.final_stage import stage_params


def test_stage_params_are_params_from_pose():
    rng = np.random.default_rng(1)
    for _ in range(300):
        base = pose_from_params(np.r_[rng.normal(size=3) * 50, rng.normal(size=3)], center=np.zeros(3))
        c = rng.normal(size=3) * 30
        pose = pose_from_params(np.r_[rng.normal(size=3) * 2, rng.normal(size=3) * 0.05], center=c, base=base)
        want = params_from_pose(pose, center=c, base=base)
        np.testing.assert_array_equal(stage_params(pose, c, base), want)

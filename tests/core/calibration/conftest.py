"""Shared fixtures of the calibration tests: a full-size rig (projections only, nothing
rendered) and a small one for rendered frames."""

import numpy as np
import pytest

from core.synthetic import foot_rig


@pytest.fixture(scope="session")
def rig():
    """The default foot rig at 1024 px (0.29 mm pixels); used for projected points only."""
    return foot_rig(seed=0, pixels=1024)


@pytest.fixture(scope="session")
def sizes(rig):
    return [(c.width, c.height) for c in rig]


@pytest.fixture
def rng():
    return np.random.default_rng(1234)

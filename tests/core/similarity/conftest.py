"""Shared fixtures of the similarity tests: a small synthetic talus case (Warp on the CPU)."""

import numpy as np
import pytest
from scipy import ndimage

from core.studies.similarity.cases import synthetic_case


@pytest.fixture(scope="session")
def talus_case():
    """Talus of a 160-px synthetic foot frame (1 mm voxels), realistic image chain, true pose."""
    return synthetic_case(bone="talus", pixels=160, spacing=1.0, device="cpu", margin=6)


@pytest.fixture(scope="session")
def smooth_pair():
    """Two independent smooth random images (48 x 40) and a bone-like DRR support on the first."""
    rng = np.random.default_rng(7)
    a = ndimage.gaussian_filter(rng.random((48, 40)), 1.5)
    b = ndimage.gaussian_filter(rng.random((48, 40)), 1.5)
    drr = a - a.min() + 0.1
    drr[:6] = 0.0
    drr[:, :4] = 0.0
    return drr, b

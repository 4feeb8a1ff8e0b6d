"""Shared fixtures of the marker tests: the thesis §4.3 lattice, rendered once per session."""

import numpy as np
import pytest

from core.synthetic.lattice import make_lattice_scene


@pytest.fixture(scope="session")
def lattice():
    return make_lattice_scene(seed=0)


@pytest.fixture(scope="session")
def lattice_frames(lattice):
    """30 noisy flatfield-corrected frames of the lattice at the thesis-like dose."""
    return lattice.frames(30, np.random.default_rng(5))

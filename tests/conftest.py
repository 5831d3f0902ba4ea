"""Shared fixtures."""

import numpy as np
import pytest


@pytest.fixture
def rng():
    """A seeded generator: every randomised test is reproducible."""
    return np.random.default_rng(20240603)

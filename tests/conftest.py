"""Shared fixtures."""

import numpy as np
import pytest


@pytest.fixture
def rng():
    """A seeded generator: every randomised test is reproducible."""
    return np.random.default_rng(20240603)


@pytest.fixture(scope="session")
def shipped_scene():
    """shipped_scene("showcase.usda") -> the path of a scene in the package's render/ data."""
    from pxr_layers.cli.demo import embedded_scene

    return embedded_scene

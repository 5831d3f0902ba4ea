"""Shared fixtures."""

import os
from pathlib import Path

import numpy as np
import pytest

SHARED = Path(__file__).resolve().parents[2] / "shared"
"""The workplace's ../shared folder beside the checkout: design notes and third-party assets
(never copied into the repo)."""
REQUIRE_SHARED = "PXR_LAYERS_REQUIRE_SHARED"
"""Set (by .ci/run) to make a missing ../shared a failure instead of a skip."""


@pytest.fixture
def rng():
    """A seeded generator: every randomised test is reproducible."""
    return np.random.default_rng(20240603)


@pytest.fixture(scope="session")
def shipped_scene():
    """shipped_scene("showcase.usda") -> the path of a scene in the package's render/ data."""
    from pxr_layers.cli.demo import embedded_scene

    return embedded_scene


@pytest.fixture(scope="session")
def shared_scenes() -> Path:
    """``../shared/scenes``: the real third-party USD assets (see _shared_folder)."""
    return _shared_folder("scenes")


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data``: third-party test data, photometric files and UsdLux test stages
    (see _shared_folder)."""
    return _shared_folder("data")


def _shared_folder(name: str) -> Path:
    """``../shared/<name>``. Skips without it, unless PXR_LAYERS_REQUIRE_SHARED is set (CI
    has it), where its absence fails."""
    folder = SHARED / name
    if folder.is_dir():
        return folder
    if os.environ.get(REQUIRE_SHARED):
        pytest.fail(f"{folder} is missing and {REQUIRE_SHARED} is set")
    pytest.skip(f"{folder} is not here (the workplace's shared assets)")


DEMO_RESOLUTION, DEMO_SPP = (64, 64), 16


@pytest.fixture(scope="session")
def demo_output(tmp_path_factory) -> Path:
    """A small `pxr-layers demo` output folder (the Cornell box's light passes, its index and
    previews), rendered once for the inspector's tests by the real console script. Tests
    that write into it copy it first."""
    import subprocess
    import sys

    folder = tmp_path_factory.mktemp("demo")
    subprocess.run([sys.executable, "-m", "pxr_layers.cli.main", "demo", "-o", str(folder), "-q",
                    "--resolution", *map(str, DEMO_RESOLUTION), "--spp", str(DEMO_SPP)], check=True)
    return folder

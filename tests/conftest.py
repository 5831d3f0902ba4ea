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


CORNELL_RESOLUTION, CORNELL_SPP = (64, 64), 16


@pytest.fixture(scope="session")
def cornell_passes(tmp_path_factory) -> Path:
    """A small render of the Cornell box into the light_passes preset (light_passes.exr,
    cornell.pxlidx, the previews), made once for the inspector's tests by the real console
    script. Tests that write into it copy it first."""
    import subprocess
    import sys

    from pxr_layers.cli.demo import embedded_scene

    folder = tmp_path_factory.mktemp("cornell")
    subprocess.run([sys.executable, "-m", "pxr_layers.cli.main", "render", str(embedded_scene("cornell.usda")),
                    "--recipe", "light_passes", "-o", str(folder), "-q", "--resolution",
                    *map(str, CORNELL_RESOLUTION), "--spp", str(CORNELL_SPP)], check=True)
    return folder

"""The embedded scenes and the inspector's page ship inside a non-editable install (a built wheel)."""

from __future__ import annotations

import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.slow
def test_wheel_carries_the_render_data(tmp_path):
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", str(ROOT), "-w", str(tmp_path)],
        check=True, capture_output=True, timeout=300,
    )
    (wheel,) = tmp_path.glob("pxr_layers-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    for data in ("cornell.usda", "showcase.usda", "textures/two_frequencies.png", "ies/spot_cos8.ies"):
        assert f"pxr_layers/render/{data}" in names
    for page in ("index.html", "app.js", "style.css"):  # the inspector's page
        assert f"pxr_layers/view/static/{page}" in names
    assert "pxr_layers/view/server.py" in names
    assert any(name.endswith("entry_points.txt") for name in names)

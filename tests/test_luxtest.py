"""The UsdLux conformance stages (luxtest, in ../shared/data) rendered end to end and compared
with the independent quadrature reference (tests/usdlux_reference.py), in the small form of
benchmarks/luxtest_table.py: the disk and sphere lights through a frame of the cone (25: a
10° cone), focus (38, 2.5) and IES (53) groups; the full table covers every group."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

TABLE = Path(__file__).resolve().parents[1] / "benchmarks" / "luxtest_table.py"


def test_shaped_and_ies_lights_match_the_usdlux_formulas(shared_data):
    assert (shared_data / "luxtest" / "usd" / "disk.usda").is_file()
    done = subprocess.run([sys.executable, str(TABLE), "--stages", "disk", "sphere", "--frames", "25", "38", "53",
                           "--resolution", "32", "--spp", "256"], capture_output=True, text=True)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "0 of the frames off" in done.stdout

"""Regenerate generatedSchema.usda and plugInfo.json from schema.usda with usdGenSchema.

    python schemas/regenerate.py           # rewrite the generated files
    python schemas/regenerate.py --check   # exit 1 (and show a diff) if they are stale

usdGenSchema ships with usd-core (``python -m pxr.Usd.usdGenSchema``) but needs jinja2,
which the usd-core wheel does not declare: install it for development (``pip install
jinja2``, it is in the ``test`` extra).

The schema is codeless (``skipCodeGeneration``), so usdGenSchema writes only the two files.
Its plugInfo.json template carries CMake placeholders (``@PLUG_INFO_*@``) that a CMake
build would fill in; here they are replaced with the values of a resource-only plugin
that sits next to its generatedSchema.usda: ``LibraryPath`` empty, ``ResourcePath`` and
``Root`` ".". usdGenSchema keeps such hand edits when it regenerates over an existing
plugInfo.json, and this script applies them again anyway, so the result is stable.
"""

from __future__ import annotations

import argparse
import difflib
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "schema.usda"
GENERATED = ("generatedSchema.usda", "plugInfo.json")
PLUG_INFO_FIXES = {
    '"@PLUG_INFO_LIBRARY_PATH@"': '""',
    '"@PLUG_INFO_RESOURCE_PATH@"': '"."',
    '"@PLUG_INFO_ROOT@"': '"."',
}


def generate(output: Path) -> dict[str, str]:
    """Run usdGenSchema on schema.usda into ``output``; return {file name: text}.

    Raises RuntimeError with usdGenSchema's output when it fails (e.g. jinja2 missing).
    """
    output.mkdir(parents=True, exist_ok=True)
    existing = HERE / "plugInfo.json"
    if existing.exists():
        shutil.copyfile(existing, output / "plugInfo.json")
    # A separate process: usdGenSchema must choose the asset resolver before anything in
    # the process creates one.
    result = subprocess.run(
        [sys.executable, "-m", "pxr.Usd.usdGenSchema", str(SOURCE), str(output)],
        capture_output=True,
        text=True,
        check=False,
    )
    if result.returncode != 0 or not all((output / name).exists() for name in GENERATED):
        raise RuntimeError(f"usdGenSchema failed:\n{result.stdout}{result.stderr}")
    plug_info = output / "plugInfo.json"
    text = plug_info.read_text()
    for placeholder, value in PLUG_INFO_FIXES.items():
        text = text.replace(placeholder, value)
    json.loads("".join(line for line in text.splitlines(True) if not line.lstrip().startswith("#")))
    plug_info.write_text(text)
    return {name: (output / name).read_text() for name in GENERATED}


def stale_files(generated: dict[str, str]) -> dict[str, str]:
    """{file name: unified diff} of the shipped files that differ from ``generated``."""
    diffs = {}
    for name, text in generated.items():
        shipped = HERE / name
        current = shipped.read_text() if shipped.exists() else ""
        if current != text:
            diffs[name] = "".join(
                difflib.unified_diff(
                    current.splitlines(True), text.splitlines(True), f"shipped/{name}", f"regenerated/{name}"
                )
            )
    return diffs


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only report stale files (exit 1 if any)")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as temporary:
        try:
            generated = generate(Path(temporary))
        except RuntimeError as error:
            sys.stderr.write(f"{error}\n")
            return 2
    diffs = stale_files(generated)
    if args.check:
        for diff in diffs.values():
            sys.stdout.write(diff)
        if diffs:
            sys.stderr.write(f"stale: {', '.join(diffs)}; run python schemas/regenerate.py\n")
        return 1 if diffs else 0
    for name, text in generated.items():
        (HERE / name).write_text(text)
    sys.stdout.write(f"wrote {', '.join(GENERATED)} in {HERE}\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())

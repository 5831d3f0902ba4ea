"""Colour facts shared by the renderer and the tools that read its outputs, importable
without the renderer (``pxr-layers extract`` must not import numba to weigh its layers).

``scene.REC709_LUMINANCE`` is the same tuple, defined there too until scene.py imports it
from here (tests/test_extract.py checks that they agree).
"""

REC709_LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Luminance weights of linear Rec.709 RGB (the rendering colour space)."""

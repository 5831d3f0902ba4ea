"""Colour facts shared by the renderer and the tools that read its outputs, importable
without the renderer (``pxr-layers extract`` must not import numba to weigh its layers).
scene.py hands them on with the rest of the plain data."""

REC709_LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Luminance weights of linear Rec.709 RGB (the rendering colour space)."""

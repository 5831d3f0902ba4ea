"""Dome lights: a lat-long map (OpenEXR orientation, +Y up) sampled from a piecewise-constant
distribution over its cells, weighted by luminance × sin θ (trace/lights.py builds it);
constant domes use the same code over a uniform grid.

Pixel column x has longitude π − 2π(x + ½)/w; row y latitude π/2 − π(y + ½)/h; direction
(cos lat · sin lon, sin lat, cos lat · cos lon) in the dome's frame.
"""

from __future__ import annotations

import math

import numpy as np

from ...compiled import inline
from .. import textures
from .distribution import pick


@inline
def dome_local(rotation, dome, x, y, z):
    """World direction (x, y, z) in dome `dome`'s frame; rotation: (D, 3, 3) dome_from_world."""
    return (rotation[dome, 0, 0] * x + rotation[dome, 0, 1] * y + rotation[dome, 0, 2] * z,
            rotation[dome, 1, 0] * x + rotation[dome, 1, 1] * y + rotation[dome, 1, 2] * z,
            rotation[dome, 2, 0] * x + rotation[dome, 2, 1] * y + rotation[dome, 2, 2] * z)


@inline
def _lat_long(lx, ly, lz):
    """Lat-long st of a dome-frame direction (st's t runs bottom to top)."""
    latitude = math.asin(min(max(ly, -1.0), 1.0))
    longitude = math.atan2(lx, lz)
    return (math.pi - longitude) / (2 * math.pi), (latitude + math.pi / 2) / math.pi


@inline
def dome_radiance(lights, dome, x, y, z):
    """Radiance (r, g, b) dome `dome` sends from unit world direction (x, y, z)."""
    r, g, b = lights.dome_radiance[dome, 0], lights.dome_radiance[dome, 1], lights.dome_radiance[dome, 2]
    texture = lights.dome_texture[dome]
    if texture < 0:
        return r, g, b
    lx, ly, lz = dome_local(lights.dome_rotation, dome, x, y, z)
    s, t = _lat_long(lx, ly, lz)
    emission = lights.emission
    i00, i10, i01, i11, fx, fy = textures.footprint(emission.texture_info, texture, s, t, 0, 2)
    texels, channels = emission.texels, emission.texture_info[texture, textures.CHANNELS]
    return (r * textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 0)),
            g * textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 1)),
            b * textures.blend(texels, i00, i10, i01, i11, fx, fy, textures.rgba_channel(channels, 2)))


@inline
def dome_pdf(lights, dome, x, y, z):
    """Solid-angle density (1/sr) of dome `dome`'s own sampling of unit world direction
    (x, y, z) (without the source's probability)."""
    lx, ly, lz = dome_local(lights.dome_rotation, dome, x, y, z)
    s, t = _lat_long(lx, ly, lz)
    rows, cols = lights.dome_rows[dome], lights.dome_columns[dome]
    column = min(max(np.int64(s * cols), 0), cols - 1)
    row = min(max(np.int64((1 - t) * rows), 0), rows - 1)
    sin_theta = math.sqrt(max(1 - ly * ly, 1e-12))
    cell = lights.dome_cell_probability[lights.dome_cell_offset[dome] + row * cols + column]
    return cell * rows * cols / (2 * math.pi * math.pi * sin_theta)


@inline
def dome_direction(lights, dome, u1, u2):
    """A unit world direction (x, y, z) from dome `dome`'s distribution: a row from u1, a
    cell of it from u2, uniform in (latitude, longitude) inside the cell."""
    rows, cols = lights.dome_rows[dome], lights.dome_columns[dome]
    row_cdf, column_cdf = lights.dome_row_cdf, lights.dome_column_cdf
    row_start, cell_start = lights.dome_row_offset[dome], lights.dome_cell_offset[dome]
    row = pick(row_cdf, row_start, rows, u1)
    row_low = row_cdf[row_start + row - 1] if row > 0 else 0.0
    row_fraction = (u1 - row_low) / max(row_cdf[row_start + row] - row_low, 1e-12)
    start = cell_start + row * cols
    column = pick(column_cdf, start, cols, u2)
    column_low = column_cdf[start + column - 1] if column > 0 else 0.0
    column_fraction = (u2 - column_low) / max(column_cdf[start + column] - column_low, 1e-12)
    v = (row + min(max(row_fraction, 0.0), 1.0)) / rows
    s = (column + min(max(column_fraction, 0.0), 1.0)) / cols
    latitude = math.pi / 2 - math.pi * v
    longitude = math.pi - 2 * math.pi * s
    lx, ly, lz = math.cos(latitude) * math.sin(longitude), math.sin(latitude), math.cos(latitude) * math.cos(longitude)
    rotation = lights.dome_rotation  # world = rotationᵀ · local (a rotation's inverse)
    return (rotation[dome, 0, 0] * lx + rotation[dome, 1, 0] * ly + rotation[dome, 2, 0] * lz,
            rotation[dome, 0, 1] * lx + rotation[dome, 1, 1] * ly + rotation[dome, 2, 1] * lz,
            rotation[dome, 0, 2] * lx + rotation[dome, 1, 2] * ly + rotation[dome, 2, 2] * lz)


@inline
def dome_sample(lights, group, dome, u1, u2):
    """Dome `dome`'s sample for link group `group` from uniforms (u1, u2). Returns sample()'s
    tuple (distance inf, pdf with the source's probability, triangle −1)."""
    dx, dy, dz = dome_direction(lights, dome, u1, u2)
    r, g, b = dome_radiance(lights, dome, dx, dy, dz)
    pdf = lights.dome_probability[group, dome] * dome_pdf(lights, dome, dx, dy, dz)
    return dx, dy, dz, math.inf, r, g, b, pdf, lights.dome_light[dome], -1

"""Texture operator T of an image, precomputed per tile and mip level, looked up per hit.

A texture multiplies the light field, so it adds its spectrum's second moments T to Σ
(``operators.texture``). A texture's spectrum is not one number: it changes across the
image (the showcase texture has two stripe frequencies side by side) and with the
footprint of the lookup (a distant, mip-filtered texture has lost its fine detail). So T
is precomputed on a grid of tiles for every mip level and interpolated at lookup time.

How one tile is measured
------------------------
* The image is reduced to one channel, the mean of its colour channels (alpha excluded).
  The material input's scale and bias are ignored: T is a property of the image.
* Tiles are ``TILE`` × ``TILE`` texels of the full-resolution image (the whole image
  when smaller), centres every ``TILE / 2`` texels; an image that is a texture's MIP
  level ``m`` (the tracer's texture cache holds the levels a frame needs) has tiles of
  ``TILE / 2^m`` texels (at least MIN_TILE), the same part of the texture. Each tile is multiplied by a Hann
  window (otherwise the tile edges add spurious high frequencies) and transformed.
* T = second moments of the amplitude spectrum |â| taken as a density, in cycles per
  texture unit (the convention of Σ: a cosine 1 + a·cos(2π f x) gives a·f²/(1 + a)).
  The window's own spectrum is measured the same way and subtracted: multiplication
  adds second moments, so tile·window has T_tile + T_window. Negative eigenvalues left
  by the subtraction are clamped to 0.
* A tile must span a couple of periods for its spectrum to resolve them: with
  ``TILE = 128`` periods up to about 64 texels are measured to a few percent (128-texel
  periods still within 2 % on the showcase), longer ones count as slowly varying
  brightness, not texture.
* Mip level m keeps the frequencies a 2^m box filter keeps, |ξ| ≤ 1/2^(m+1) cycles per
  texel on each axis, so T(level m) is the moment of the band-limited tile. Levels stop
  once the cut-off falls inside the window's main lobe: beyond that T is 0.

Units: T blocks are (s, t) texture units: cycles² per texture unit² (multiply by the
uv Jacobian, ``operators.texture_to_tangent``, for cycles²/m²). t runs up the image
(row 0 of ``pixels`` is the top), so the (s, t) cross term has the opposite sign of the
(column, row) one.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

logger = logging.getLogger(__name__)

TILE = 128  # texels of the full-resolution image per analysis tile
MIN_TILE = 8  # texels of a tile of a texture's coarse MIP level at least
TILES_AT_ONCE = 512
"""Tiles whose spectra are computed together (about 0.3 GiB of float64 and complex arrays):
memory stays bounded whatever the texture's size."""


@dataclass(frozen=True)
class TextureSpectrum:
    """T of one image on a grid of tile centres, per mip level.

    blocks : (levels, rows, cols, 3) float32 [T_ss, T_st, T_tt], cycles² per texture
             unit²; row 0 is the tile at the top of the image (t = 1)
    centres_s : (cols,) s of the tile centres; centres_t : (rows,) t of the tile centres
    width, height : texels of the full-resolution image
    """

    blocks: np.ndarray
    centres_s: np.ndarray
    centres_t: np.ndarray
    width: int
    height: int

    @classmethod
    def of_image(cls, pixels: np.ndarray, level: int = 0) -> TextureSpectrum:
        """Measure T for every tile and level of `pixels` (h, w, c) float, row 0 = top: a
        texture's MIP level `level` (0: its full resolution)."""
        image = np.asarray(pixels)
        if image.ndim == 3:  # the colour channels: RGB, or the grey of grey (+ alpha)
            # in float64 without a float64 copy of every channel first (a large texture's GiBs)
            image = image[..., :3].mean(axis=2, dtype=np.float64) if image.shape[2] >= 3 else image[..., 0]
        image = np.asarray(image, dtype=np.float64)
        height, width = image.shape
        tile = max(MIN_TILE, TILE >> level)
        tile_h, tile_w = min(tile, height), min(tile, width)
        rows = _tile_starts(height, tile_h)
        cols = _tile_starts(width, tile_w)
        window = np.outer(_hann(tile_h), _hann(tile_w))
        # Real input: the half spectrum of rfft2 (columns 0..w/2) with every column that
        # stands for a ±pair counted twice has the same moments as the full one.
        freq_row = np.fft.fftfreq(tile_h)[:, None]  # cycles per texel
        freq_col = np.fft.rfftfreq(tile_w)[None, :]
        pair_weight = np.full(freq_col.shape, 2.0)
        pair_weight[0, 0] = 1.0
        if tile_w % 2 == 0:
            pair_weight[0, -1] = 1.0
        level_count = _level_count(tile_h, tile_w)
        masks = [_band(freq_row, freq_col, level) * pair_weight for level in range(level_count)]
        window_moments = [_moments(np.abs(np.fft.rfft2(window)), freq_row, freq_col, mask) for mask in masks]

        blocks = np.zeros((level_count, len(rows), len(cols), 3), np.float32)
        # A few rows of tiles at a time: each tile is measured alone, and the spectra of all
        # of a large texture's tiles at once would take GiBs (tiles overlap: 4 × its texels).
        group = max(1, TILES_AT_ONCE // len(cols))
        for first in range(0, len(rows), group):
            chosen = rows[first : first + group]
            tiles = np.stack([image[r : r + tile_h, c : c + tile_w] for r in chosen for c in cols])
            spectra = np.abs(np.fft.rfft2(tiles * window))  # (tiles, tile_h, tile_w // 2 + 1)
            for level, mask in enumerate(masks):
                col_col, col_row, row_row = _moments(spectra, freq_row, freq_col, mask)
                w_cc, w_cr, w_rr = window_moments[level]
                # texels -> texture units: s = col / width, t = 1 - row / height
                ss = (col_col - w_cc) * width**2
                st = -(col_row - w_cr) * width * height
                tt = (row_row - w_rr) * height**2
                blocks[level, first : first + len(chosen)] = np.stack(
                    _clamp_psd(ss, st, tt), axis=-1).reshape(len(chosen), len(cols), 3)
        centres_s = (np.asarray(cols) + tile_w / 2) / width
        centres_t = 1.0 - (np.asarray(rows) + tile_h / 2) / height
        logger.debug("texture spectrum: %dx%d texels, %d×%d tiles, %d levels", width, height, len(rows),
                     len(cols), level_count)
        return cls(blocks, centres_s, centres_t, width, height)

    def lookup(self, st: np.ndarray, footprint_texels: np.ndarray) -> np.ndarray:
        """T at texture coordinates st (2, n) for lookups `footprint_texels` (n,) wide.

        The level is log2 of the footprint (rounded), clamped to the levels measured; st is
        clamped to the tile grid and interpolated bilinearly between tile centres.
        Returns (n, 2, 2) float64, cycles² per texture unit².
        """
        st = np.asarray(st, dtype=np.float64)
        footprint = np.maximum(np.asarray(footprint_texels, dtype=np.float64), 1.0)
        level = np.clip(np.rint(np.log2(footprint)), 0, len(self.blocks) - 1).astype(np.intp)
        col, col_frac = _grid_position(st[0], self.centres_s)
        row, row_frac = _grid_position(st[1], self.centres_t)
        col_next = np.minimum(col + 1, len(self.centres_s) - 1)
        row_next = np.minimum(row + 1, len(self.centres_t) - 1)
        grid = self.blocks
        col_frac, row_frac = col_frac[:, None], row_frac[:, None]
        top = grid[level, row, col] * (1 - col_frac) + grid[level, row, col_next] * col_frac
        bottom = grid[level, row_next, col] * (1 - col_frac) + grid[level, row_next, col_next] * col_frac
        ss, st_, tt = np.moveaxis(top * (1 - row_frac) + bottom * row_frac, -1, 0)
        return np.stack([np.stack([ss, st_], -1), np.stack([st_, tt], -1)], -2)


def _tile_starts(size: int, tile: int) -> list[int]:
    """First texel of each tile: every tile/2 texels, the last one flush with the edge."""
    hop = max(tile // 2, 1)
    starts = list(range(0, size - tile + 1, hop))
    if starts[-1] != size - tile:
        starts.append(size - tile)
    return starts


def _hann(size: int) -> np.ndarray:
    """A Hann window of `size` non-zero samples."""
    return np.hanning(size + 2)[1:-1] if size > 1 else np.ones(1)


def _level_count(tile_h: int, tile_w: int) -> int:
    """Levels whose cut-off 1/2^(m+1) stays above the window's main lobe (2/tile)."""
    main_lobe = 2.0 / min(tile_h, tile_w)
    levels = 1
    while 0.5 / 2**levels > main_lobe:
        levels += 1
    return levels


def _band(freq_row: np.ndarray, freq_col: np.ndarray, level: int) -> np.ndarray:
    cutoff = 0.5 / 2**level + 1e-12
    return (np.abs(freq_row) <= cutoff) & (np.abs(freq_col) <= cutoff)


def _moments(amplitude: np.ndarray, freq_row, freq_col, mask) -> tuple[np.ndarray, ...]:
    """Second moments (col·col, col·row, row·row) of amplitude (..., h, w) weighted by mask."""
    weights = amplitude * mask
    total = np.maximum(weights.sum(axis=(-2, -1)), 1e-300)
    return tuple(
        (weights * product).sum(axis=(-2, -1)) / total
        for product in (freq_col * freq_col, freq_col * freq_row, freq_row * freq_row)
    )


def _clamp_psd(a: np.ndarray, b: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, ...]:
    """The symmetric 2×2 [[a, b], [b, d]] with negative eigenvalues set to 0."""
    half_trace = 0.5 * (a + d)
    radius = np.sqrt((0.5 * (a - d)) ** 2 + b * b)
    high = np.maximum(half_trace + radius, 0.0)
    low = np.maximum(half_trace - radius, 0.0)
    angle = 0.5 * np.arctan2(2 * b, a - d)  # direction of the larger eigenvalue
    c, s = np.cos(angle), np.sin(angle)
    return high * c * c + low * s * s, (high - low) * c * s, high * s * s + low * c * c


def _grid_position(coordinate: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cell index i (so that centres i, i+1 bracket it) and fraction, clamped to the grid.

    `centres` may run up or down; a single centre gives index 0 and fraction 0.
    """
    if len(centres) == 1:
        return np.zeros(len(coordinate), np.intp), np.zeros(len(coordinate))
    ascending = centres[1] > centres[0]
    axis = centres if ascending else centres[::-1]
    position = np.interp(coordinate, axis, np.arange(len(axis), dtype=np.float64))
    if not ascending:
        position = len(axis) - 1 - position
    index = np.clip(np.floor(position).astype(np.intp), 0, len(centres) - 2)
    return index, position - index

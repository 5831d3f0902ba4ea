"""RenderRequest: one set of defaults, validated; variant selections parsed."""

from __future__ import annotations

from pathlib import Path

import pytest

from pxr_layers.errors import RenderSettingsError
from pxr_layers.request import MAX_SUBDIV_LEVEL, RenderRequest, VariantSelection


def test_variant_selections_parse_and_print_back():
    selection = VariantSelection.parse("/World/Teapot:modelVariant=Fancy")
    assert (selection.prim, selection.variant_set, selection.value) == ("/World/Teapot", "modelVariant", "Fancy")
    assert str(selection) == "/World/Teapot:modelVariant=Fancy"
    assert VariantSelection.parse("/A/B:look=").value == ""  # the empty selection is USD's "none"
    for bad in ("World:look=red", "/World:look", "/World=red", "/World:a:b=c"):
        with pytest.raises(RenderSettingsError, match="PRIM:SET=VALUE"):
            VariantSelection.parse(bad)


def test_requests_check_their_numbers():
    assert RenderRequest("shot.usda").stage == Path.cwd() / "shot.usda"  # absolute: metadata must not depend on the cwd
    for fields in ({"spp": 0}, {"max_depth": -1}, {"norm_bounces": -2}, {"spp": 1.5}, {"seed": -1},
                   {"subdiv_level": MAX_SUBDIV_LEVEL + 1}, {"resolution": (0, 10)}):
        with pytest.raises(RenderSettingsError):
            RenderRequest("shot.usda", **fields)


def test_the_norm_bounce_rule():
    request = RenderRequest("shot.usda", max_depth=8)
    assert request.resolved_norm_bounces(5, has_conditions=False) == 5
    assert request.resolved_norm_bounces(5, has_conditions=True) == 8  # a condition under .* tests any bounce
    assert RenderRequest("shot.usda", norm_bounces=2).resolved_norm_bounces(5, has_conditions=True) == 2
    # Nothing reads norms without an index, a condition or the debug maps: none are traced
    # unless asked for.
    unindexed = RenderRequest("shot.usda", keep_index=False)
    assert unindexed.resolved_norm_bounces(5, has_conditions=False) == 0
    assert unindexed.resolved_norm_bounces(5, has_conditions=True) == 8
    assert RenderRequest("shot.usda", keep_index=False, norm_bounces=3).resolved_norm_bounces(5, False) == 3
    debug = RenderRequest("shot.usda", keep_index=False, debug_covariance=True)
    assert debug.resolved_norm_bounces(0, has_conditions=False) == 1

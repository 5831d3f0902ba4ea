"""The inspector's path-class descriptions and generalised LPEs, against the LPE language
itself: every LPE it offers must select what it says."""

from __future__ import annotations

import itertools

import pytest

from pxr_layers import lpe
from pxr_layers.paths.events import event_paths, path_text
from pxr_layers.paths.reader import PathIndex
from pxr_layers.view import inspect


@pytest.fixture(scope="module")
def index(cornell_passes) -> PathIndex:
    return PathIndex(cornell_passes / "cornell.pxlidx")


@pytest.fixture(scope="module")
def infos(index):
    paths = event_paths(index.events)
    return [inspect.describe(path_class, paths) for path_class in index.classes]


def test_each_class_s_lpe_matches_it_and_says_its_parts(index, infos):
    for path_class, info in zip(index.classes[:2000], infos):
        assert lpe.compile(info.lpe).matches(path_class.events), info
        assert info.path == path_text(path_class.events)
    direct = next(info for info in infos if info.path == "C RD'redWall' L'ceilingLight'")
    assert (direct.light, direct.first_object, direct.first_material, direct.scattering, direct.bounces) == \
        ("ceilingLight", "redWall", "red", "D", 1)


@pytest.mark.parametrize("keep", [(), ("light",), ("first_object",), ("first_material", "light"),
                                  ("first_scattering", "bounces"), ("light", "first_object", "bounces"),
                                  ("scattering",), ("scattering", "first_object", "light")])
def test_a_generalised_lpe_matches_every_class_it_came_from(index, infos, keep):
    groups = itertools.islice((infos[i:i + 7] for i in range(0, len(infos), 997)), 40)
    for group in groups:
        expression = lpe.compile(inspect.generalise(group, keep))
        for info in group:
            assert expression.matches(index.classes[info.id].events), (keep, info.path, expression.text)


def test_what_is_kept_is_what_the_lpe_tests(index, infos):
    """Keeping the light and first object: a path from another light or first object fails."""
    red = [info for info in infos if info.first_object == "redWall" and info.light == "ceilingLight"][:20]
    expression = lpe.compile(inspect.generalise(red, ["light", "first_object"]))
    assert expression.text == "C<..'redWall'>.*<L.'ceilingLight'>"
    others = [info for info in infos if info.first_object not in ("redWall", "")][:200]
    assert not any(expression.matches(index.classes[info.id].events) for info in others)


def test_unknown_aspects_are_refused(infos):
    with pytest.raises(ValueError, match="colour"):
        inspect.generalise(infos[:2], ["colour"])

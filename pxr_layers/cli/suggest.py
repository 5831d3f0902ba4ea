"""`pxr-layers suggest`: find light layers automatically, as a USD recipe and its EXRs."""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

from ..errors import OutputError
from ..recipe.model import DEFAULT_CAMERA_PATH, RECIPE_SUFFIXES, Layer, Product, Recipe
from ..suggest import DEFAULT_K, MAX_ELBOW_K, STRATEGIES
from .render import nonempty_path, positive_int

DEFAULT_RECIPE_NAME = "suggested.usda"
"""The recipe's name beside the first index when -o is not given."""

HELP = "suggest light layers that partition the beauty, named and explained, for one index or a shot's frames"
DESCRIPTION = (
    "Cluster the light paths of INDEX (one or more .pxlidx: the frames of one shot give one set of layers "
    "for all of them) into K layers, each an LPE named after what it holds (key_on_floor, lamp_via_mirror, ...) "
    "with a one-line explanation, chosen by splitting path space by light, bounce count, the first bounce's "
    "object, material, type, scattering and covariance (flat/curved, plain/textured, matte/shiny), and what "
    "the whole path touches (any bounce's object, material or asset), under the objective of docs/suggest.md "
    "(separated in the picture, nameable); without -k, K is the objective's elbow. The layers partition the "
    "beauty (checked with the LPE automaton on every path class). "
    "Writes a USD recipe (-o) that `extract --recipe` and `render --recipe` accept, and beside it, per index, "
    "the multipart EXR, previews and contact sheet with each layer's share."
)


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("indexes", nargs="+", type=nonempty_path, metavar="INDEX", help="path indexes (.pxlidx) of one shot")
    add_search_options(parser)


def add_search_options(parser: argparse.ArgumentParser, default_recipe: str | None = None) -> None:
    """Every option but the indexes: shared with `pxr-layers job suggest`, which finds them in the job."""
    parser.add_argument("-k", "--layers", type=positive_int, default=DEFAULT_K, metavar="N",
                        help="how many layers (default: the elbow of the objective over 1 to "
                        f"{MAX_ELBOW_K} layers, docs/suggest.md; fewer when path space cannot be split further)")
    parser.add_argument("--exclude", action="append", default=[], metavar="EXPR",
                        help="an expression of a layer already in the stack: a suggested layer that cuts the same "
                        "paths is not offered again (repeat for more)")
    parser.add_argument("-o", "--output", type=nonempty_path, metavar="RECIPE",
                        help=f"the recipe to write ({', '.join(RECIPE_SUFFIXES)}); the EXRs go beside it, named "
                        f"after it (default: {default_recipe or DEFAULT_RECIPE_NAME + ' beside the first index'})")
    parser.add_argument("--strategy", choices=STRATEGIES, default=STRATEGIES[0],
                        help=f"how the layers are searched for (default {STRATEGIES[0]}; docs/suggest.md)")
    parser.add_argument("--threads", type=positive_int, default=2, metavar="N",
                        help="threads that read and decode each index's chunks with their covariance (default 2)")
    parser.add_argument("--no-exr", action="store_true", help="write the recipe only, not the EXRs and previews")
    parser.add_argument("--no-previews", action="store_true", help="do not write the PNG previews and contact sheets")


def run(args: argparse.Namespace) -> int:
    from ..layers.deliver import index_inputs
    from ..outputs import reading
    from ..paths.reader import PathIndex

    indexes = [PathIndex(path) for path in args.indexes]
    # The indexes and the renders' EXRs beside them are never replaced by what suggest writes
    # (-o out/shot.usda beside out/shot.pxlidx would otherwise write its EXR over out/shot.exr).
    with reading(*(path for index in indexes for path in index_inputs(index))):
        return _suggest(indexes, args)


def _suggest(indexes: list, args: argparse.Namespace) -> int:
    from ..layers.deliver import at_index_view, beauty_beside, deliver, index_frame, index_metadata, plan_outputs
    from ..layers.extract import extraction_threads
    from ..outputs import OutputSet, check_output
    from ..stage.recipe_writer import write_recipe
    from ..suggest import suggest

    target = Path(args.output) if args.output else indexes[0].path.parent / DEFAULT_RECIPE_NAME
    check_output(target, "recipe", RECIPE_SUFFIXES)  # before the search: a mistake costs nothing
    suggestion = suggest(indexes, args.layers, strategy=args.strategy, threads=args.threads, exclude=args.exclude)
    if not suggestion.layers:
        raise OutputError("every suggested layer is already in the stack (--exclude): nothing to write")
    recipe = suggested_recipe(suggestion.layers, indexes[0], target.stem, suggestion.explanations)
    plans = []  # (index, its recipe, product → EXR), every name checked before anything is written
    written: dict[Path, Path] = {}  # EXR → the index it is cut from
    for index in indexes if not args.no_exr else ():
        at_index = dataclasses.replace(recipe, products=(at_index_view(recipe.products[0], index),))
        outputs = plan_outputs(at_index, index_frame(index), target.parent)
        for exr in outputs.values():
            other = written.setdefault(exr, index.path)
            if other != index.path:  # two frames at one time (or none): one EXR would silently replace the other
                raise OutputError(f"{exr}: both {other} and {index.path} would write it (the same frame "
                                  "time); suggest for each on its own, with its own -o")
        plans.append((index, at_index, outputs))
    width = max(len(name) for name in suggestion.layers)
    for name, expression in suggestion.layers.items():
        print(f"{name:<{width}}  {suggestion.shares[name]:6.1%}  {expression}")
        print(f"{'':<{width}}          {suggestion.explanations[name]}")
    for name, expression in suggestion.already.items():
        print(f"{name:<{width}}  already in the stack as {expression}")
    how = (f"K = {len(suggestion.objectives)} asked" if suggestion.chosen_k == "given" else
           f"K = {len(suggestion.layers) + len(suggestion.already)} at the elbow of "
           + " ".join(f"{value:.3f}" for value in suggestion.objectives))
    print(f"objective {suggestion.objective:.4f} ({suggestion.strategy}; {how}; "
          f"splits: {', '.join(suggestion.splits) or 'none'})")
    with OutputSet(), extraction_threads(args.threads):  # the recipe and every EXR of the command, or none
        write_recipe(target, recipe)
        for index, at_index, outputs in plans:
            for delivered in deliver(index, at_index, beauty_beside(index), outputs,
                                     metadata=index_metadata(index, target.parent), previews=not args.no_previews):
                print(delivered.exr)
    print(target)
    return 0


def suggested_recipe(layers: dict[str, str], index, name: str, explanations: dict[str, str] | None = None) -> Recipe:
    """One product of the suggested layers at the view of `index` (its camera and resolution).

    name : the recipe file's stem, also the EXRs' (``<name>.exr``, a frame number added per
           frame); made a prim name, it is the product's
    explanations : layer → its one-line explanation, each RenderVar's documentation
    """
    from ..stage.recipe_writer import valid_prim_name

    return Recipe(products=(Product(
        name=valid_prim_name(name), output_name=f"{name}.exr", camera=index.manifest.get("camera", DEFAULT_CAMERA_PATH),
        resolution=tuple(index.manifest["resolution"]),
        layers=tuple(Layer(layer, "lpe", expression, group="suggested", description=(explanations or {}).get(layer, ""))
                     for layer, expression in layers.items())),))

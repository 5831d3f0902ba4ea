"""Light Path Expressions: OSL's query language plus covariance conditions, compiled to one automaton.

Entry points::

    expression = compile("C<RD>.*<L.'key'>")
    expression.matches("C RD'floor' RG'chrome' L'key'")            # True
    expression.canonical                                            # "C<RD>.*<L.'key'>"

    recipe = compile_layers({"diffuse": "C<RD>.*", "flat": "C D@(|S_C| = 0) .*"})
    outcomes = recipe.match([Event("C"), Event("R", "D", {"floor"}), Event("L")])
    outcomes["flat"].mask(norms)                                    # (r,) bool per record

Modules: ``lexer`` and ``parser`` (text → tree), ``nodes`` (tree, canonical form),
``conditions`` (covariance conditions), ``automaton`` (NFA, DFA, minimisation, matching),
``outcomes`` (never / always / conditional masks), ``paths`` (textual path notation),
``reference`` (slow matcher on the tree), ``passes`` (standard light passes), ``sets``
(exclusive and remainder layers, with the set difference ``A - B``), ``hints``
(notes on likely slips), ``testing`` (random trees and paths for property tests).
The language is documented in docs/lpe.md.
"""

from .automaton import LayerAutomaton
from .conditions import MUCH_GREATER_FACTOR
from .events import Event
from .expression import EXPRESSION_LAYER, Expression, compile, compile_layers
from .hints import hints
from .labels import closest_labels
from .nodes import canonical
from .outcomes import ALWAYS, NEVER, Conditional, Outcome
from .parser import parse
from .passes import BEAUTY, STANDARD_PASSES, per_light_passes
from .paths import PathText, format_path, parse_path
from .reference import reference_match
from .sets import exclusive, remainder

__all__ = [
    "ALWAYS",
    "BEAUTY",
    "EXPRESSION_LAYER",
    "MUCH_GREATER_FACTOR",
    "NEVER",
    "STANDARD_PASSES",
    "Conditional",
    "Event",
    "Expression",
    "LayerAutomaton",
    "Outcome",
    "PathText",
    "canonical",
    "closest_labels",
    "compile",
    "compile_layers",
    "exclusive",
    "format_path",
    "hints",
    "parse",
    "parse_path",
    "per_light_passes",
    "reference_match",
    "remainder",
]

"""What an expression may hold and what its automaton may grow to: every limit, in one place.

Each keeps a hostile or mistyped expression from costing unbounded time or memory, far
above what any light path needs (docs/lpe.md, "Limits"). The automaton's choices between
building the complete DFA and building it on demand are budgets of :mod:`.automaton`, not
limits: they change how an expression is matched, never whether it is accepted.
"""

from __future__ import annotations

import numpy as np

MAX_QUERY_LENGTH = 1_000_000
"""Most characters of one expression (a megabyte: labels and spaces are read at memory speed)."""

MAX_TOKENS = 50_000
"""Most tokens of one expression: letters, labels, operators, bounds, and inside conditions
each number, quantity, comparator, word and parenthesis. Reading one takes microseconds, so
this keeps parsing well under a second, and is far above any expression a path needs (a
per-light expression lists each light's label once: a rig of 20 000 lights fits)."""

MAX_REPETITION = 100
"""Largest bound of ``{n,m}``: paths are never that long, and each copy costs automaton states."""

MAX_NESTING = 32
"""Groups ``(...)`` and sets ``[...]`` nested in one another at most, and parentheses in one
condition likewise (far beyond any path a light takes, and well inside what the recursive
parsers and the compiler can descend)."""

MAX_NFA_STATES = 2000
"""Most states of the NFA of one expression, counted on the parse tree before anything is
built (``automaton.nfa_state_count``; repetitions multiply the size of what they repeat, so
``C(R{1,100}){1,100}L`` would have 20 207). The parser refuses an expression past it at the
repetition, or the item or alternative, that takes it past. ``C.{0,100}L`` has 207 states and
the expressions of the docs, tests, recipes and standard passes at most 130; 2000 keeps
compiling one expression well under a second."""

MAX_DFA_STATES = 50_000
"""Most DFA states built for one automaton (a recipe's layers together). Subset construction
can need 2**n states (``C.*R.{n}L`` remembers which of its last n events were R); the
complete DFA is not built past this (it is then built on demand), and an automaton built on
demand raises an LpeError when matching needs more."""

LARGEST_NUMBER = float(np.finfo(np.float32).max)
"""Largest magnitude of a number in a condition or a value in the path notation (about
3.4e38): values are compared in float32, and a larger number (``1e999`` reads as infinity)
would have no canonical spelling that parses back."""

"""The sandbox that runs LLM-written event programs (``def parse_event(): ...``).

The program text is parsed with ``ast.parse``, checked against an allow-list, and run by a
small tree-walking interpreter: Python's ``exec``/``eval``/``compile`` never see it, and the
program never holds a real Python object model (no frames, globals, builtins, classes,
``str.format``). Programs see:

- the names of ``namespace`` (spatial-API functions and constants; read-only: containers are
  copied on first use, and no name may be rebound),
- a few built-ins (``builtin_functions.BUILTINS``) and allow-listed methods of
  str / list / dict / tuple / set (``methods.METHODS``),
- attributes listed by a type's ``sandbox_attributes: ClassVar[frozenset[str]]``
  (e.g. the character handle's ``set_position``), never a name starting with ``_``,
- operators on other types only if the type lists the symbol in ``sandbox_operators``.

Guarantee: every failure is an ``EventProgramError`` with a one-line ``feedback`` naming the
program line. ``ToolError`` from a tool propagates unchanged (line added); a program may
catch it with ``try/except`` (``except ToolError``, ``except Exception``, a ``ToolError``
subclass name, or bare ``except``), never a budget or sandbox error. ``Budget`` bounds steps,
loops, sizes, recursion and time (an injected clock: the thread's CPU time by default), every size checked before the value is built.

Modules, in dependency order: ``errors`` (every sandbox failure type), ``budget`` (limits and
the meter), ``boundary`` (values entering and leaving the program), ``operators``,
``builtin_functions``, ``methods``, ``checker`` (the static allow-list check), ``values``
(scopes and program functions), ``access`` (attributes, items, tool calls), ``statements``
and ``interpreter`` (the tree walk), ``runner`` (the public entry).

Imports: the standard library (``ast``, no ``exec``), ``storyteller.tools.errors`` and this package; no
other ``tools`` module, nothing of ``sim``, and no clock except ``runner``'s default for the
injected ``clock`` parameter.
"""

from storyteller.tools.sandbox.budget import Budget
from storyteller.tools.sandbox.checker import check_program
from storyteller.tools.sandbox.errors import (
    BudgetExceededError,
    ForbiddenConstructError,
    MissingEntryError,
    ProgramRuntimeError,
    ProgramSyntaxError,
    UnknownNameError,
)
from storyteller.tools.sandbox.runner import ProgramRun, execute, run_program

__all__ = [
    "Budget",
    "BudgetExceededError",
    "ForbiddenConstructError",
    "MissingEntryError",
    "ProgramRun",
    "ProgramRuntimeError",
    "ProgramSyntaxError",
    "UnknownNameError",
    "check_program",
    "execute",
    "run_program",
]

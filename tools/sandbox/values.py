"""Runtime values the interpreter creates: scopes, program functions, built-in and method
handles, and the control-flow signals of statements.

A program never holds a real Python callable: ``def`` / ``lambda`` become ``SandboxFunction``
(only the interpreter calls it), a built-in name becomes ``BuiltinFunction``, ``obj.method``
becomes ``BoundMethod``; none of them exposes an attribute to the program (``INTERNAL_TYPES``).
"""

from __future__ import annotations

import ast
from typing import Final

from storyteller.tools.sandbox.builtin_functions import BUILTINS, BuiltinImpl
from storyteller.tools.sandbox.methods import MethodImpl

MISSING: Final = object()
"""Marks a name not found in a scope (``None`` is a value)."""


class Scope:
    """Variables of one function call (or the module, or a comprehension).

    ``local_names`` are the names the function binds (None for the module and for
    comprehensions, which look names up in their parent).
    """

    __slots__ = ("local_names", "parent", "vars")

    def __init__(
        self, vars: dict[str, object], parent: Scope | None, local_names: frozenset[str] | None
    ) -> None:
        self.vars = vars
        self.parent = parent
        self.local_names = local_names


class SandboxFunction:
    """A function defined by the program (``def`` or ``lambda``); only the sandbox calls it."""

    __slots__ = (
        "body",
        "closure",
        "defaults",
        "lambda_body",
        "line",
        "local_names",
        "name",
        "params",
    )

    def __init__(
        self,
        name: str,
        params: list[str],
        defaults: list[object],
        body: list[ast.stmt],
        lambda_body: ast.expr | None,
        closure: Scope,
        local_names: frozenset[str],
        line: int,
    ) -> None:
        self.name = name
        self.params = params
        self.defaults = defaults
        self.body = body
        self.lambda_body = lambda_body
        self.closure = closure
        self.local_names = local_names
        self.line = line

    def __repr__(self) -> str:
        return f"<function {self.name}>"


class BuiltinFunction:
    """A built-in function as a program holds it."""

    __slots__ = ("impl", "name")

    def __init__(self, name: str, impl: BuiltinImpl) -> None:
        self.name = name
        self.impl = impl

    def __repr__(self) -> str:
        return f"<built-in function {self.name}>"


class BoundMethod:
    """``obj.method`` as a program holds it: the receiver and an allow-listed method."""

    __slots__ = ("impl", "name", "obj")

    def __init__(self, obj: object, name: str, impl: MethodImpl) -> None:
        self.obj = obj
        self.name = name
        self.impl = impl

    def __repr__(self) -> str:
        return f"<method {type(self.obj).__name__}.{self.name}>"


class Return:
    """What a ``return`` statement passes up through the blocks of its function."""

    __slots__ = ("value",)

    def __init__(self, value: object) -> None:
        self.value = value


BUILTIN_FUNCTIONS: Final = {name: BuiltinFunction(name, impl) for name, impl in BUILTINS.items()}
BREAK: Final = object()
"""What a ``break`` statement returns to its loop."""
CONTINUE: Final = object()
"""What a ``continue`` statement returns to its loop."""
INTERNAL_TYPES: Final = frozenset({SandboxFunction, BuiltinFunction, BoundMethod})
"""Types whose attributes and operators a program never reaches."""

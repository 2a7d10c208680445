"""The boolean expressions of the reference test cases, parsed once into a small tree.

Both kinds of expected-plan expression share one grammar: action expressions over labels
(``order_food || order_drink``) and relationship / position expressions over atoms
(``close to table_3 || (in front of chair_1 && in front of chair_3)``)::

    or    := and ( "||" and )*
    and   := unary ( "&&" unary )*
    unary := "!" unary | "(" or ")" | ATOM
    ATOM  := any run of text without | & ! ( ), surrounding blanks stripped

so negation binds tighter than ``&&``, which binds tighter than ``||``. Negation is written
``!`` for both kinds, as the authors' action evaluator reads it (``!eat``); it applies to an
atom or a parenthesised group (``!(eat || drink)``, ``!close to table_3``).

Guarantee: :func:`parse_expression` either returns a tree whose atoms are exactly the
non-blank texts between operators, or raises :class:`ExpressionError` (or the subclass the
caller names) whose message names the expression and the 1-based column of the offending
token. What an atom means is left to the caller (:mod:`storyteller.benchmark.plan_scoring` for actions,
:mod:`storyteller.benchmark.position_check` for positions); this module only reads the structure.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from dataclasses import dataclass

_OPERATOR_CHARS = frozenset("|&!()")


class ExpressionError(ValueError):
    """An expression that cannot be read; ``column`` is 1-based (0 for an empty expression)."""

    def __init__(self, message: str, expression: str, column: int) -> None:
        self.message, self.expression, self.column = message, expression, column
        where = f" at column {column}" if column else ""
        super().__init__(f"{message}{where} in '{expression}'")


@dataclass(frozen=True)
class Atom:
    text: str
    column: int
    """1-based column of the atom's first character in the expression."""


@dataclass(frozen=True)
class Not:
    operand: Expr


@dataclass(frozen=True)
class And:
    operands: tuple[Expr, ...]


@dataclass(frozen=True)
class Or:
    operands: tuple[Expr, ...]


Expr = Atom | Not | And | Or


@dataclass(frozen=True)
class _Token:
    kind: str  # "||", "&&", "!", "(", ")" or "atom"
    text: str
    column: int


def _tokens(expression: str, error: type[ExpressionError]) -> list[_Token]:
    tokens: list[_Token] = []
    i, n = 0, len(expression)
    while i < n:
        ch = expression[i]
        if ch.isspace():
            i += 1
        elif expression.startswith(("||", "&&"), i):
            tokens.append(_Token(expression[i:i + 2], expression[i:i + 2], i + 1))
            i += 2
        elif ch in "|&":
            raise error(f"single '{ch}' (write '{ch * 2}')", expression, i + 1)
        elif ch in "!()":
            tokens.append(_Token(ch, ch, i + 1))
            i += 1
        else:
            j = i
            while j < n and expression[j] not in _OPERATOR_CHARS:
                j += 1
            tokens.append(_Token("atom", expression[i:j].strip(), i + 1))
            i = j
    return tokens


def parse_expression(expression: str, *, error: type[ExpressionError] = ExpressionError) -> Expr:
    """The tree of ``expression`` (see the module docstring); raises ``error`` when malformed."""
    tokens = _tokens(expression, error)
    if not tokens:
        raise error("empty expression", expression, 0)
    pos = 0

    def fail(message: str) -> ExpressionError:
        if pos < len(tokens):
            return error(f"{message}, found '{tokens[pos].text}'", expression, tokens[pos].column)
        return error(f"{message}, found the end", expression, len(expression) + 1)

    def parse_chain(op: str, operand: Callable[[], Expr], node: type[And | Or]) -> Expr:
        """Operands joined by ``op`` (one operand alone is itself, not a ``node``)."""
        nonlocal pos
        operands = [operand()]
        while pos < len(tokens) and tokens[pos].kind == op:
            pos += 1
            operands.append(operand())
        return operands[0] if len(operands) == 1 else node(tuple(operands))

    def parse_or() -> Expr:
        return parse_chain("||", parse_and, Or)

    def parse_and() -> Expr:
        return parse_chain("&&", parse_unary, And)

    def parse_unary() -> Expr:
        nonlocal pos
        if pos >= len(tokens):
            raise fail("expected an operand")
        token = tokens[pos]
        if token.kind == "!":
            pos += 1
            return Not(parse_unary())
        if token.kind == "(":
            pos += 1
            inner = parse_or()
            if pos >= len(tokens) or tokens[pos].kind != ")":
                raise fail(f"expected ')' to close the '(' at column {token.column}")
            pos += 1
            return inner
        if token.kind == "atom":
            pos += 1
            return Atom(token.text, token.column)
        raise fail("expected an operand")

    tree = parse_or()
    if pos != len(tokens):
        raise fail("expected '||', '&&' or the end")
    return tree


def atoms(tree: Expr) -> Iterator[Atom]:
    """The atoms of ``tree``, left to right."""
    if isinstance(tree, Atom):
        yield tree
    elif isinstance(tree, Not):
        yield from atoms(tree.operand)
    else:
        for operand in tree.operands:
            yield from atoms(operand)


def evaluate(tree: Expr, holds: Callable[[Atom], bool]) -> bool:
    """Whether ``tree`` holds when each atom holds as ``holds`` says (every atom is visited, so
    an atom ``holds`` rejects with an error is reported even where the result is already known)."""
    if isinstance(tree, Atom):
        return holds(tree)
    if isinstance(tree, Not):
        return not evaluate(tree.operand, holds)
    values = [evaluate(operand, holds) for operand in tree.operands]
    return all(values) if isinstance(tree, And) else any(values)

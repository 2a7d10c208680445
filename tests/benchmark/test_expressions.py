"""The expression grammar shared by action and position expressions: precedence (``!`` over
``&&`` over ``||``), parentheses, and typed errors that name the expression and the column."""

from __future__ import annotations

import pytest
from hypothesis import given
from hypothesis import strategies as st

from storyteller.benchmark.expressions import (
    And,
    Atom,
    Expr,
    ExpressionError,
    Not,
    Or,
    atoms,
    evaluate,
    parse_expression,
)
from storyteller.benchmark.plan_scoring import ActionExpressionError, action_matches, parse_action_expression
from storyteller.benchmark.position_check import PositionExpressionError


def test_precedence_and_grouping() -> None:
    assert parse_expression("a || b && c") == Or((Atom("a", 1), And((Atom("b", 6), Atom("c", 11)))))
    assert parse_expression("(a || b) && c") == And((Or((Atom("a", 2), Atom("b", 7))), Atom("c", 13)))
    assert parse_expression("!a && b") == And((Not(Atom("a", 2)), Atom("b", 7)))
    assert parse_expression("!(a || b)") == Not(Or((Atom("a", 3), Atom("b", 8))))
    assert parse_expression("!!a") == Not(Not(Atom("a", 3)))
    tree = parse_expression("close to table_3 || (in front of chair_1 && in front of chair_3)")
    assert [a.text for a in atoms(tree)] == ["close to table_3", "in front of chair_1", "in front of chair_3"]


def test_action_semantics_with_negation() -> None:
    assert action_matches("!eat", "drink") and not action_matches("!eat", "eat")
    assert action_matches("!(eat || drink)", "read_book") and not action_matches("!(eat || drink)", "drink")
    assert action_matches("!eat && !drink || eat", "eat")  # (!eat && !drink) || eat
    assert not action_matches("!(eat && !drink || eat)", "eat")
    assert action_matches("eat || drink && read_book", "eat")  # && binds tighter


@pytest.mark.parametrize(("expression", "message", "column"), [
    ("", "empty expression", 0),
    ("   ", "empty expression", 0),
    ("eat ||", "expected an operand, found the end", 7),
    ("eat || && drink", "expected an operand, found '&&'", 8),
    ("(eat || drink", "expected ')' to close the '(' at column 1, found the end", 14),
    ("eat )", "expected '||', '&&' or the end, found ')'", 5),
    ("eat | drink", "single '|' (write '||')", 5),
    ("eat & drink", "single '&' (write '&&')", 5),
    ("eat !drink", "expected '||', '&&' or the end, found '!'", 5),
    ("()", "expected an operand, found ')'", 2),
    ("!", "expected an operand, found the end", 2),
])
def test_malformed_expressions_name_the_expression_and_column(expression: str, message: str, column: int) -> None:
    with pytest.raises(ExpressionError) as info:
        parse_expression(expression)
    assert info.value.message == message and info.value.column == column
    assert f"'{expression}'" in str(info.value)


def test_each_kind_raises_its_own_type() -> None:
    with pytest.raises(ActionExpressionError, match=r"'eat; drink' is not an action label at column 1"):
        parse_action_expression("eat; drink")
    with pytest.raises(ActionExpressionError, match="at column 8"):
        action_matches("eat || (drink", "eat")
    from storyteller.sim.scene.model import Scene, SceneObject

    scene = Scene(name="s", bounds_min=(0.0, 0.0), bounds_max=(4.0, 4.0), objects=(
        SceneObject(name="table_1", label="table", idx=1, center=(2.0, 2.0, 0.4), size=(1.0, 1.0, 0.8)),))
    from storyteller.benchmark.position_check import check_position

    with pytest.raises(PositionExpressionError, match=r"unknown object 'table_2' at column 21 in"):
        check_position(scene, "close to table_1 || close to table_2", (0.5, 0.5))
    with pytest.raises(PositionExpressionError, match=r"cannot read 'hovering over table_1'.* at column 2"):
        check_position(scene, "!hovering over table_1", (0.5, 0.5))
    assert issubclass(PositionExpressionError, ValueError) and issubclass(ActionExpressionError, ValueError)


# ----- round trip: any tree, printed with full parentheses, parses back to itself -------------
_labels = st.sampled_from(["eat", "drink", "read_book", "close to table_1", "sit on chair_2"])


def _trees() -> st.SearchStrategy[Expr]:
    leaf = _labels.map(lambda t: Atom(t, 0))
    return st.recursive(leaf, lambda inner: st.one_of(
        inner.map(Not),
        st.lists(inner, min_size=2, max_size=3).map(lambda xs: And(tuple(xs))),
        st.lists(inner, min_size=2, max_size=3).map(lambda xs: Or(tuple(xs))),
    ), max_leaves=8)


def _render(tree: Expr) -> str:
    if isinstance(tree, Atom):
        return tree.text
    if isinstance(tree, Not):
        return f"!({_render(tree.operand)})"
    op = " && " if isinstance(tree, And) else " || "
    return op.join(f"({_render(o)})" for o in tree.operands)


def _strip_columns(tree: Expr) -> Expr:
    if isinstance(tree, Atom):
        return Atom(tree.text, 0)
    if isinstance(tree, Not):
        return Not(_strip_columns(tree.operand))
    flat: list[Expr] = []
    for operand in tree.operands:  # a parenthesised group of the same operator reads back as one level
        o = _strip_columns(operand)
        flat += list(o.operands) if type(o) is type(tree) else [o]
    return type(tree)(tuple(flat))


def _python(tree: Expr, truth: dict[str, bool]) -> bool:
    if isinstance(tree, Atom):
        return truth[tree.text]
    if isinstance(tree, Not):
        return not _python(tree.operand, truth)
    values = [_python(o, truth) for o in tree.operands]
    return all(values) if isinstance(tree, And) else any(values)


@given(_trees(), st.fixed_dictionaries({t: st.booleans() for t in
                                        ["eat", "drink", "read_book", "close to table_1", "sit on chair_2"]}))
def test_printed_trees_parse_back_and_evaluate_alike(tree: Expr, truth: dict[str, bool]) -> None:
    text = _render(tree)
    parsed = parse_expression(text)
    assert _strip_columns(parsed) == _strip_columns(tree)
    for atom in atoms(parsed):
        assert text[atom.column - 1:].startswith(atom.text)
    assert evaluate(parsed, lambda a: truth[a.text]) == _python(tree, truth)

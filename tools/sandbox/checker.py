"""The static check of an event program: parse it, then walk its tree against an allow-list.

Runs before any of the program does. Only the node types listed here are allowed; imports,
classes, ``global``, ``with``, ``yield``, ``raise``, names and attributes starting with ``_``,
rebinding a spatial-API name, and names defined nowhere are refused, every problem as an
``EventProgramError`` on its line (the earliest is raised). The checker also records each
function's local names for the interpreter.

The check is bounded like a run: the text by ``Budget.source_chars``, the tree by
``check_nodes`` and ``nesting_depth``, the distinct names by ``check_names``, and the time by
``check_time`` on the injected clock (checked every 256 nodes); a "did you mean" hint is
computed only for the one problem reported, on a bounded number of candidates. Results are
cached per (source, namespace names, budget), failures included (except running out of
time, which depends on the machine), in a cache bounded in bytes (``CACHE_BYTES``, each
entry charged for its text and tree). Cached trees are shared: callers must not mutate them.
"""

from __future__ import annotations

import ast
import warnings
from collections import OrderedDict
from collections.abc import Callable, Mapping, Sequence
from typing import Final, TypeAlias

from storyteller.tools import errors
from storyteller.tools.errors import EventProgramError, ToolError, did_you_mean
from storyteller.tools.sandbox.budget import Budget
from storyteller.tools.sandbox.builtin_functions import BUILTINS, PYTHON_ONLY_BUILTINS
from storyteller.tools.sandbox.errors import (
    BudgetExceededError,
    ForbiddenConstructError,
    ProgramSyntaxError,
    UnknownNameError,
)


def _node_types(names: str) -> frozenset[type[ast.AST]]:
    return frozenset(getattr(ast, name) for name in names.split())


_STATEMENTS = _node_types(
    "FunctionDef Return Assign AugAssign AnnAssign For While If Expr Pass Break Continue "
    "Assert Try ExceptHandler Delete"
)
_EXPRESSIONS = _node_types(
    "BoolOp BinOp UnaryOp Compare IfExp Call keyword Constant Name Attribute Subscript Slice "
    "List Tuple Dict Set ListComp SetComp DictComp GeneratorExp comprehension JoinedStr "
    "FormattedValue Lambda NamedExpr Starred arguments arg"
)
_LEAVES = _node_types(
    "Load Store Del And Or Add Sub Mult Div FloorDiv Mod Pow LShift RShift BitOr BitXor BitAnd "
    "Invert Not UAdd USub Eq NotEq Lt LtE Gt GtE Is IsNot In NotIn"
)
_ALLOWED = _STATEMENTS | _EXPRESSIONS | _LEAVES | {ast.Module}
# Allowed nodes with no check of their own (only their children are visited).
_PLAIN = _ALLOWED - _node_types(
    "Name Attribute Constant keyword Starred Return Break Continue FunctionDef Lambda "
    "ExceptHandler List Tuple Set Call For While comprehension"
)

_FORBIDDEN_MESSAGES: dict[type[ast.AST], str] = {
    ast.Import: "imports are not allowed; the spatial-API functions are already defined",
    ast.ImportFrom: "imports are not allowed; the spatial-API functions are already defined",
    ast.ClassDef: "class definitions are not allowed; use dicts, lists or tuples",
    ast.Global: "'global' is not allowed; pass values as arguments and return results",
    ast.Nonlocal: "'nonlocal' is not allowed; pass values as arguments and return results",
    ast.With: "'with' is not allowed",
    ast.AsyncWith: "async code is not allowed",
    ast.AsyncFor: "async code is not allowed",
    ast.AsyncFunctionDef: "async code is not allowed",
    ast.Await: "async code is not allowed",
    ast.Yield: "generators ('yield') are not allowed; build and return a list",
    ast.YieldFrom: "generators ('yield') are not allowed; build and return a list",
    ast.Raise: "'raise' is not allowed; a failing spatial-API call already reports the problem",
    ast.Match: "'match' is not allowed; use if/elif",
    ast.TryStar: "'except*' is not allowed",
    ast.MatMult: "the '@' operator is not supported",
}

# Exception names a program may catch (they all catch tool errors only).
CATCHABLE: dict[str, type[EventProgramError]] = {
    "Exception": ToolError,
    "EventProgramError": ToolError,
    "ToolError": ToolError,
    **{
        name: cls
        for name, cls in vars(errors).items()
        if isinstance(cls, type) and issubclass(cls, ToolError)
    },
}

_SKIPPED_FIELDS = frozenset({"returns", "annotation", "type_comment", "ctx"})
_FIELDS: dict[type[ast.AST], tuple[str, ...]] = {}


def _children(node: ast.AST) -> list[ast.AST]:
    """Child nodes, skipping annotations (never evaluated) and Load/Store contexts."""
    t = type(node)
    fields = _FIELDS.get(t)
    if fields is None:
        fields = _FIELDS[t] = tuple(f for f in t._fields if f not in _SKIPPED_FIELDS)
    out: list[ast.AST] = []
    for field in fields:
        value = getattr(node, field, None)
        if type(value) is list:
            out.extend(v for v in value if isinstance(v, ast.AST))
        elif isinstance(value, ast.AST):
            out.append(value)
    return out


def _parse(source: object, budget: Budget) -> ast.Module:
    if not isinstance(source, str):
        raise ProgramSyntaxError(
            f"the program must be Python source text, not '{type(source).__name__}'"
        )
    if len(source) > budget.source_chars:
        raise BudgetExceededError(
            f"the program has {len(source)} characters (limit {budget.source_chars})"
        )
    try:
        with warnings.catch_warnings():  # e.g. "invalid escape sequence": not the LLM's problem
            warnings.simplefilter("ignore")
            return ast.parse(source, mode="exec")
    except SyntaxError as err:
        line = err.lineno if isinstance(err.lineno, int) else None
        text = f"syntax error: {err.msg}"
        if err.text and line is not None:
            text += f" in `{err.text.strip()[:80]}`"
        raise ProgramSyntaxError(text, line=line) from None
    except (ValueError, TypeError) as err:  # e.g. null bytes
        raise ProgramSyntaxError(f"the program text cannot be parsed: {err}") from None
    except (RecursionError, MemoryError):
        raise BudgetExceededError(
            "the program nests expressions too deeply to parse; write simpler expressions"
        ) from None


Checked: TypeAlias = tuple[ast.Module, dict[int, frozenset[str]]]
"""A checked tree and each function's local names (keyed by the id of its node)."""

CACHE_BYTES: Final = 32 * 2**20
"""Bytes the check cache may hold (estimated: ``NODE_BYTES`` per tree node plus the text)."""
NODE_BYTES: Final = 400
"""Estimated bytes of one syntax-tree node with its attributes."""
ERROR_BYTES: Final = 1_000
"""Estimated bytes of a cached failure."""


class _CheckCache:
    """Least recently used checks, bounded by their estimated bytes."""

    def __init__(self, max_bytes: int) -> None:
        self.max_bytes = max_bytes
        self.bytes = 0
        self.entries: OrderedDict[
            tuple[str, frozenset[str], Budget], tuple[Checked | EventProgramError, int]
        ] = OrderedDict()

    def get(self, key: tuple[str, frozenset[str], Budget]) -> Checked | EventProgramError | None:
        entry = self.entries.get(key)
        if entry is None:
            return None
        self.entries.move_to_end(key)
        return entry[0]

    def put(
        self,
        key: tuple[str, frozenset[str], Budget],
        value: Checked | EventProgramError,
        size: int,
    ) -> None:
        if size > self.max_bytes or key in self.entries:
            return
        self.entries[key] = (value, size)
        self.bytes += size
        while self.bytes > self.max_bytes:
            _, (_, old) = self.entries.popitem(last=False)
            self.bytes -= old


_CACHE = _CheckCache(CACHE_BYTES)


class CheckTimeoutError(BudgetExceededError):
    """The static check ran out of its time (not cached: it depends on the machine)."""


def _fresh(err: EventProgramError) -> EventProgramError:
    """A new exception equal to a cached one (raising one instance twice chains tracebacks)."""
    copy = type(err)(err.feedback)
    copy.line = err.line
    return copy


def check_program(
    source: object,
    namespace: Mapping[str, object],
    *,
    budget: Budget | None = None,
    clock: Callable[[], float] | None = None,
) -> Checked:
    """Parse and statically check a program; return its tree and each function's local names.

    Raises the problem on the earliest line (syntax, forbidden construct, unknown name), or
    ``BudgetExceededError`` when the program is too large to check or the check takes longer
    than ``budget.check_time`` on ``clock`` (None: no time limit, only the size limits).
    """
    budget = budget or Budget()
    if not isinstance(source, str):
        return _check(source, frozenset(), budget, clock)[0]
    reserved = frozenset(k for k in namespace if not k.startswith("_"))
    key = (source, reserved, budget)
    cached = _CACHE.get(key)
    if isinstance(cached, EventProgramError):
        raise _fresh(cached)
    if cached is not None:
        return cached
    try:
        checked, nodes = _check(source, reserved, budget, clock)
    except CheckTimeoutError:
        raise
    except EventProgramError as err:
        _CACHE.put(key, _fresh(err), len(source) + ERROR_BYTES)
        raise
    _CACHE.put(key, checked, len(source) + nodes * NODE_BYTES)
    return checked


def _check(
    source: object, reserved: frozenset[str], budget: Budget, clock: Callable[[], float] | None
) -> tuple[Checked, int]:
    """The check and the number of tree nodes it visited."""
    tree = _parse(source, budget)
    checker = _Checker(reserved, budget, clock)
    checker.visit(tree, 0, 0)
    problem = checker.first_problem()
    if problem is not None:
        raise problem
    return (tree, checker.local_names), checker.nodes


class _Checker:
    """Walks the tree once, collecting problems (reported earliest line first).

    ``visit(node, flags, depth)``: ``flags`` has bit 1 inside a function, bit 2 inside a loop.
    Also records each function's local names (what its body binds, comprehension targets
    excluded) for the interpreter.
    """

    def __init__(
        self, reserved: frozenset[str], budget: Budget, clock: Callable[[], float] | None
    ) -> None:
        self.reserved = reserved
        self.budget = budget
        self.clock = clock
        self.deadline = None if clock is None else clock() + budget.check_time
        self.nodes = 0
        self.names: set[str] = set()
        self.problems: list[tuple[int, int, EventProgramError]] = []
        self.bound: set[str] = set()
        self.loads: list[ast.Name] = []
        self.local_names: dict[int, frozenset[str]] = {}
        self.starred_ok: set[int] = set()
        self.scopes: list[set[str]] = [set()]

    def problem(self, node: ast.AST, err_type: type[EventProgramError], message: str) -> None:
        line = getattr(node, "lineno", 0) or 0
        err = err_type(message, line=line or None)
        self.problems.append((line, getattr(node, "col_offset", 0), err))

    def forbid(self, node: ast.AST, message: str) -> None:
        self.problem(node, ForbiddenConstructError, message)

    def check_binding(self, node: ast.AST, name: str) -> None:
        """A name the program defines (variable, function, parameter, except target)."""
        self.bound.add(name)
        self.scopes[-1].add(name)
        if name.startswith("_") and name != "_":
            self.forbid(node, f"names starting with '_' are not allowed ('{name}')")
        elif name in self.reserved:
            self.forbid(
                node,
                f"'{name}' is a spatial-API name and cannot be reassigned or redefined; "
                "use another name",
            )

    def visit_all(self, nodes: Sequence[ast.AST], flags: int, depth: int) -> None:
        for child in nodes:
            self.visit(child, flags, depth)

    def count(self, node: ast.AST) -> None:
        """One more node visited: the tree size, name count and clock limits."""
        self.nodes += 1
        budget = self.budget
        if self.nodes > budget.check_nodes:
            raise BudgetExceededError(
                f"the program has more than {budget.check_nodes} syntax nodes; "
                "event programs are a few dozen lines",
                line=getattr(node, "lineno", None),
            )
        if not self.nodes & 255:
            if len(self.names) > budget.check_names:
                raise BudgetExceededError(
                    f"the program uses more than {budget.check_names} different names; "
                    "event programs need only a few",
                    line=getattr(node, "lineno", None),
                )
            if (
                self.clock is not None
                and self.deadline is not None
                and self.clock() > self.deadline
            ):
                raise CheckTimeoutError(
                    f"checking the program took longer than {budget.check_time:g} s; "
                    "write a shorter program"
                )

    def visit(self, node: ast.AST, flags: int, depth: int) -> None:
        self.count(node)
        if depth > self.budget.nesting_depth:
            raise BudgetExceededError(
                f"the program nests more than {self.budget.nesting_depth} levels deep; "
                "write simpler expressions",
                line=getattr(node, "lineno", None),
            )
        depth += 1
        t = type(node)
        if t in _PLAIN:
            self.visit_all(_children(node), flags, depth)
            return
        if isinstance(node, ast.Name):
            self.check_name(node)
        elif isinstance(node, ast.Constant):
            self.check_constant(node)
        elif isinstance(node, ast.Attribute):
            attr = node.attr
            self.names.add(attr)
            if attr.startswith("_"):
                self.forbid(node, f"attributes starting with '_' are not allowed ('.{attr}')")
            if type(node.ctx) is not ast.Load:
                self.forbid(
                    node, "assigning or deleting attributes is not allowed; call methods instead"
                )
            self.visit(node.value, flags, depth)
        elif isinstance(node, ast.Call | ast.List | ast.Tuple | ast.Set):
            elts = node.args if isinstance(node, ast.Call) else node.elts
            self.starred_ok.update(id(e) for e in elts if type(e) is ast.Starred)
            self.visit_all(_children(node), flags, depth)
        elif isinstance(node, ast.keyword):
            arg = node.arg
            if arg is not None and arg.startswith("_"):
                self.forbid(node, f"keyword arguments starting with '_' are not allowed ('{arg}')")
            self.visit(node.value, flags, depth)
        elif isinstance(node, ast.Starred):
            if id(node) not in self.starred_ok:
                self.forbid(
                    node,
                    "'*' unpacking is only allowed in calls, list/tuple/set displays and assignments",
                )
            self.visit(node.value, flags, depth)
        elif t is ast.Return:
            if not flags & 1:
                self.forbid(node, "'return' outside a function")
            self.visit_all(_children(node), flags, depth)
        elif t is ast.Break or t is ast.Continue:
            if not flags & 2:
                self.forbid(node, f"'{t.__name__.lower()}' outside a loop")
        elif isinstance(node, ast.For | ast.While):
            head: list[ast.AST] = (
                [node.target, node.iter] if isinstance(node, ast.For) else [node.test]
            )
            self.visit_all(head, flags, depth)
            self.visit_all(node.body, flags | 2, depth)
            self.visit_all(node.orelse, flags, depth)
        elif isinstance(node, ast.comprehension):
            if node.is_async:
                self.forbid(node, "async code is not allowed")
            self.scopes.append(set())  # comprehension targets are not function locals
            self.visit(node.target, flags, depth)
            self.scopes.pop()
            self.visit(node.iter, flags, depth)
            self.visit_all(node.ifs, flags, depth)
        elif isinstance(node, ast.FunctionDef | ast.Lambda):
            self.visit_function(node, depth)
        elif isinstance(node, ast.ExceptHandler):
            self.visit_handler(node, flags, depth)
        else:
            message = _FORBIDDEN_MESSAGES.get(t, f"'{t.__name__}' is not allowed in event programs")
            self.forbid(node, message)

    def check_name(self, node: ast.Name) -> None:
        self.names.add(node.id)
        if type(node.ctx) is ast.Load:
            self.loads.append(node)
            if node.id.startswith("_") and node.id != "_":
                hint = (
                    " (drop any `if __name__ == '__main__':` block; parse_event() is called for you)"
                    if node.id == "__name__"
                    else ""
                )
                self.forbid(node, f"names starting with '_' are not allowed ('{node.id}'){hint}")
        else:
            self.check_binding(node, node.id)

    def check_constant(self, node: ast.Constant) -> None:
        v = node.value
        t = type(v)
        if type(v) is int:
            if v.bit_length() > self.budget.int_bits:
                self.problem(
                    node,
                    BudgetExceededError,
                    f"an integer literal has {v.bit_length()} bits (limit {self.budget.int_bits})",
                )
        elif type(v) is str:
            if len(v) > self.budget.str_len:
                self.problem(
                    node,
                    BudgetExceededError,
                    f"a string literal has {len(v)} characters (limit {self.budget.str_len})",
                )
        elif t not in (float, bool, type(None)):
            kind = {
                bytes: "bytes literals",
                complex: "complex numbers",
                type(...): "'...' literals",
            }.get(t, t.__name__)
            self.forbid(node, f"{kind} are not supported")

    def visit_function(self, node: ast.FunctionDef | ast.Lambda, depth: int) -> None:
        if isinstance(node, ast.FunctionDef):
            self.check_binding(node, node.name)
            if node.decorator_list:
                self.forbid(node, "decorators are not allowed")
        args = node.args
        if args.vararg or args.kwarg or args.kwonlyargs:
            self.forbid(
                node,
                "only plain positional parameters (with optional defaults) are supported; no *args, **kwargs or keyword-only parameters",
            )
        params = [a.arg for a in (*args.posonlyargs, *args.args)]
        if len(set(params)) != len(params):
            self.forbid(node, "duplicate parameter names")
        self.visit_all(args.defaults, 0, depth)
        self.scopes.append(set())
        for a in (*args.posonlyargs, *args.args):
            self.check_binding(a, a.arg)
        body: Sequence[ast.AST] = node.body if isinstance(node, ast.FunctionDef) else [node.body]
        self.visit_all(body, 1, depth)
        self.local_names[id(node)] = frozenset(self.scopes.pop())

    def visit_handler(self, node: ast.ExceptHandler, flags: int, depth: int) -> None:
        names: list[ast.expr] = []
        if isinstance(node.type, ast.Tuple):
            names = list(node.type.elts)
        elif node.type is not None:
            names = [node.type]
        for n in names:
            if not (isinstance(n, ast.Name) and n.id in CATCHABLE):
                self.forbid(
                    n,
                    "only tool errors can be caught: use `except ToolError`, `except Exception` "
                    "or a ToolError subclass name",
                )
        if node.name is not None:
            self.check_binding(node, node.name)
        self.visit_all(node.body, flags, depth)

    def first_problem(self) -> EventProgramError | None:
        """The problem on the earliest line, unknown names included.

        The "did you mean" hint is computed only for an unknown name that is reported, on at
        most ``budget.suggestion_candidates`` known names.
        """
        if len(self.names) > self.budget.check_names:
            return BudgetExceededError(
                f"the program uses more than {self.budget.check_names} different names; "
                "event programs need only a few"
            )
        known = self.bound | self.reserved | BUILTINS.keys()
        unknown = min(
            (n for n in self.loads if n.id not in known and not n.id.startswith("_")),
            key=lambda n: (n.lineno, n.col_offset),
            default=None,
        )
        if unknown is not None:
            name = unknown.id
            if name in PYTHON_ONLY_BUILTINS:
                self.forbid(unknown, f"'{name}' is not available in event programs")
            else:
                self.problem(unknown, UnknownNameError, f"name '{name}' is not defined;")
        if not self.problems:
            return None
        err = min(self.problems, key=lambda p: (p[0], p[1]))[2]
        if type(err) is UnknownNameError and unknown is not None:
            # the likeliest names first: same initial, then similar length
            first, size = unknown.id[:1], len(unknown.id)
            candidates = sorted(known, key=lambda k: (k[:1] != first, abs(len(k) - size), k))
            candidates = candidates[: self.budget.suggestion_candidates]
            hint = did_you_mean(unknown.id, candidates, n=1)
            return UnknownNameError(
                f"name '{unknown.id}' is not defined;"
                + (hint or " no such function or variable exists"),
                line=err.line,
            )
        return err

"""The sandbox that runs LLM-written event programs (``def parse_event(): ...``).

The program text is parsed with ``ast.parse``, checked against an allow-list, and run by a
small tree-walking interpreter: Python's ``exec``/``eval``/``compile`` never see it, and the
program never holds a real Python object model (no frames, globals, builtins, classes,
``str.format``). Programs see:

- the names of ``namespace`` (spatial-API functions and constants; read-only: containers are
  copied on first use, and no name may be rebound),
- a few built-ins (``tools.sandbox.builtins.BUILTINS``) and allow-listed methods of
  str / list / dict / tuple / set,
- attributes listed by a type's ``sandbox_attributes: ClassVar[frozenset[str]]``
  (e.g. the character handle's ``set_position``), never a name starting with ``_``,
- operators on other types only if the type lists the symbol in ``sandbox_operators``.

Every failure is an ``EventProgramError`` with a one-line ``feedback`` naming the program
line. ``ToolError`` from a tool propagates unchanged (line added); a program may catch it
with ``try/except`` (``except ToolError``, ``except Exception``, a ``ToolError`` subclass
name, or bare ``except``), never a budget or sandbox error. ``Budget`` bounds steps, loops,
sizes, recursion and (injected-clock) wall time.

Checked trees are cached per (source, namespace names, budget); ``check_program`` returns
them shared, so callers must not mutate them. Program calls use about 15 Python frames per
level: a caller already near Python's recursion limit gets ``BudgetExceededError`` earlier.
"""

from __future__ import annotations

import ast
import contextlib
import functools
import inspect
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from tools import errors
from tools.errors import EventProgramError, ToolError, did_you_mean
from tools.sandbox.budget import (
    Budget,
    BudgetExceededError,
    ForbiddenConstructError,
    Meter,
    MissingEntryError,
    ProgramRuntimeError,
    ProgramSyntaxError,
    UnknownNameError,
)
from tools.sandbox.builtins import (
    BUILTINS,
    METHODS,
    OPERAND_TYPES,
    PYTHON_ONLY_BUILTINS,
    BuiltinImpl,
    MethodImpl,
    binary,
    check_hash_spread,
    check_key,
    compare,
    detach,
    format_value,
    iter_source,
    materialize,
    to_text,
    type_name,
    unary,
)

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

Line = int | None


@dataclass(frozen=True)
class ProgramRun:
    """What one successful run produced: the entry's return value and the printed lines."""

    result: object
    output: tuple[str, ...]
    steps: int


def execute(
    source: str,
    namespace: Mapping[str, object],
    *,
    entry: str = "parse_event",
    budget: Budget | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> object:
    """Run ``source``'s module body, then ``entry()``; return what ``entry`` returns.

    Raises only ``EventProgramError`` subclasses (``ToolError`` from tools unchanged).
    """
    return run_program(source, namespace, entry=entry, budget=budget, clock=clock).result


def run_program(
    source: str,
    namespace: Mapping[str, object],
    *,
    entry: str = "parse_event",
    budget: Budget | None = None,
    clock: Callable[[], float] = time.monotonic,
) -> ProgramRun:
    """Like ``execute`` but also returns the captured ``print`` output and the step count."""
    budget = budget or Budget()
    interpreter: _Interpreter | None = None
    try:
        tree, local_names = check_program(source, namespace, budget=budget)
        interpreter = _Interpreter(namespace, budget, clock, local_names)
        result = interpreter.run(tree, entry)
        return ProgramRun(result, tuple(interpreter.meter.output), interpreter.meter.steps)
    except EventProgramError as err:
        if interpreter is not None:
            err.steps = interpreter.meter.steps
        raise
    except (RecursionError, MemoryError):
        raise BudgetExceededError(
            "the program nests or recurses too deeply, or uses too much memory"
        ) from None
    except (Exception, SystemExit, KeyboardInterrupt) as err:  # never let anything else out
        raise ProgramRuntimeError(f"the program failed: {type(err).__name__}: {err}") from None


# ---------------------------------------------------------------- static checks


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
_CATCHABLE: dict[str, type[EventProgramError]] = {
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


def check_program(
    source: object, namespace: Mapping[str, object], *, budget: Budget | None = None
) -> tuple[ast.Module, dict[int, frozenset[str]]]:
    """Parse and statically check a program; return its tree and each function's local names.

    Raises the problem on the earliest line (syntax, forbidden construct, unknown name).
    """
    budget = budget or Budget()
    if isinstance(source, str):
        reserved = frozenset(k for k in namespace if not k.startswith("_"))
        return _check_cached(source, reserved, budget)
    return _check(source, frozenset(), budget)


@functools.lru_cache(maxsize=128)
def _check_cached(
    source: str, reserved: frozenset[str], budget: Budget
) -> tuple[ast.Module, dict[int, frozenset[str]]]:
    """Checked trees are cached: the interpreter never mutates them (same program, many seeds)."""
    return _check(source, reserved, budget)


def _check(
    source: object, reserved: frozenset[str], budget: Budget
) -> tuple[ast.Module, dict[int, frozenset[str]]]:
    tree = _parse(source, budget)
    checker = _Checker(reserved, budget)
    checker.visit(tree, 0, 0)
    checker.check_names()
    if checker.problems:
        checker.problems.sort(key=lambda p: (p[0], p[1]))
        raise checker.problems[0][2]
    return tree, checker.local_names


class _Checker:
    """Walks the tree once, collecting problems (reported earliest line first).

    ``visit(node, flags, depth)``: ``flags`` has bit 1 inside a function, bit 2 inside a loop.
    Also records each function's local names (what its body binds, comprehension targets
    excluded) for the interpreter.
    """

    def __init__(self, reserved: frozenset[str], budget: Budget) -> None:
        self.reserved = reserved
        self.budget = budget
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

    def visit_all(self, nodes: list[ast.AST], flags: int, depth: int) -> None:
        for child in nodes:
            self.visit(child, flags, depth)

    def visit(self, node: ast.AST, flags: int, depth: int) -> None:
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
        if t is ast.Name:
            self.check_name(node)  # type: ignore[arg-type]
        elif t is ast.Constant:
            self.check_constant(node)  # type: ignore[arg-type]
        elif t is ast.Attribute:
            attr = node.attr  # type: ignore[attr-defined]
            if attr.startswith("_"):
                self.forbid(node, f"attributes starting with '_' are not allowed ('.{attr}')")
            if type(node.ctx) is not ast.Load:  # type: ignore[attr-defined]
                self.forbid(
                    node, "assigning or deleting attributes is not allowed; call methods instead"
                )
            self.visit(node.value, flags, depth)  # type: ignore[attr-defined]
        elif t is ast.Call or t is ast.List or t is ast.Tuple or t is ast.Set:
            elts = node.args if t is ast.Call else node.elts  # type: ignore[attr-defined]
            self.starred_ok.update(id(e) for e in elts if type(e) is ast.Starred)
            self.visit_all(_children(node), flags, depth)
        elif t is ast.keyword:
            arg = node.arg  # type: ignore[attr-defined]
            if arg is not None and arg.startswith("_"):
                self.forbid(node, f"keyword arguments starting with '_' are not allowed ('{arg}')")
            self.visit(node.value, flags, depth)  # type: ignore[attr-defined]
        elif t is ast.Starred:
            if id(node) not in self.starred_ok:
                self.forbid(
                    node,
                    "'*' unpacking is only allowed in calls, list/tuple/set displays and assignments",
                )
            self.visit(node.value, flags, depth)  # type: ignore[attr-defined]
        elif t is ast.Return:
            if not flags & 1:
                self.forbid(node, "'return' outside a function")
            self.visit_all(_children(node), flags, depth)
        elif t is ast.Break or t is ast.Continue:
            if not flags & 2:
                self.forbid(node, f"'{t.__name__.lower()}' outside a loop")
        elif t is ast.For or t is ast.While:
            loop: ast.For | ast.While = node  # type: ignore[assignment]
            head: list[ast.AST] = (
                [loop.target, loop.iter] if isinstance(loop, ast.For) else [loop.test]
            )
            self.visit_all(head, flags, depth)
            self.visit_all(loop.body, flags | 2, depth)  # type: ignore[arg-type]
            self.visit_all(loop.orelse, flags, depth)  # type: ignore[arg-type]
        elif t is ast.comprehension:
            comp: ast.comprehension = node  # type: ignore[assignment]
            self.scopes.append(set())  # comprehension targets are not function locals
            self.visit(comp.target, flags, depth)
            self.scopes.pop()
            self.visit(comp.iter, flags, depth)
            self.visit_all(comp.ifs, flags, depth)  # type: ignore[arg-type]
        elif t is ast.FunctionDef or t is ast.Lambda:
            self.visit_function(node, depth)  # type: ignore[arg-type]
        elif t is ast.ExceptHandler:
            self.visit_handler(node, flags, depth)  # type: ignore[arg-type]
        else:
            message = _FORBIDDEN_MESSAGES.get(t, f"'{t.__name__}' is not allowed in event programs")
            self.forbid(node, message)

    def check_name(self, node: ast.Name) -> None:
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
        if t is int:
            if v.bit_length() > self.budget.int_bits:
                self.problem(
                    node,
                    BudgetExceededError,
                    f"an integer literal has {v.bit_length()} bits (limit {self.budget.int_bits})",
                )
        elif t is str:
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
        self.visit_all(args.defaults, 0, depth)  # type: ignore[arg-type]
        self.scopes.append(set())
        for a in (*args.posonlyargs, *args.args):
            self.check_binding(a, a.arg)
        body: list[ast.AST] = node.body if isinstance(node, ast.FunctionDef) else [node.body]  # type: ignore[assignment]
        self.visit_all(body, 1, depth)
        self.local_names[id(node)] = frozenset(self.scopes.pop())

    def visit_handler(self, node: ast.ExceptHandler, flags: int, depth: int) -> None:
        names: list[ast.expr] = []
        if isinstance(node.type, ast.Tuple):
            names = list(node.type.elts)
        elif node.type is not None:
            names = [node.type]
        for n in names:
            if not (isinstance(n, ast.Name) and n.id in _CATCHABLE):
                self.forbid(
                    n,
                    "only tool errors can be caught: use `except ToolError`, `except Exception` "
                    "or a ToolError subclass name",
                )
        if node.name is not None:
            self.check_binding(node, node.name)
        self.visit_all(node.body, flags, depth)  # type: ignore[arg-type]

    def check_names(self) -> None:
        known = self.bound | self.reserved | BUILTINS.keys()
        for node in self.loads:
            name = node.id
            if name in known or name.startswith("_"):
                continue
            if name in PYTHON_ONLY_BUILTINS:
                self.forbid(node, f"'{name}' is not available in event programs")
            else:
                hint = (
                    did_you_mean(name, sorted(known), n=1) or " no such function or variable exists"
                )
                self.problem(node, UnknownNameError, f"name '{name}' is not defined;{hint}")


# ---------------------------------------------------------------- runtime values

_MISSING = object()


class _Scope:
    __slots__ = ("local_names", "parent", "vars")

    def __init__(
        self, vars: dict[str, object], parent: _Scope | None, local_names: frozenset[str] | None
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
        closure: _Scope,
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
    __slots__ = ("impl", "name")

    def __init__(self, name: str, impl: BuiltinImpl) -> None:
        self.name = name
        self.impl = impl

    def __repr__(self) -> str:
        return f"<built-in function {self.name}>"


class BoundMethod:
    __slots__ = ("impl", "name", "obj")

    def __init__(self, obj: object, name: str, impl: MethodImpl) -> None:
        self.obj = obj
        self.name = name
        self.impl = impl

    def __repr__(self) -> str:
        return f"<method {type(self.obj).__name__}.{self.name}>"


class _Return:
    __slots__ = ("value",)

    def __init__(self, value: object) -> None:
        self.value = value


_BUILTIN_FUNCTIONS = {name: BuiltinFunction(name, impl) for name, impl in BUILTINS.items()}
_BREAK = object()
_CONTINUE = object()
_INTERNAL = frozenset({SandboxFunction, BuiltinFunction, BoundMethod})
_METHOD_ERRORS = (TypeError, ValueError, IndexError, KeyError, AttributeError, OverflowError)


def _add_line(err: EventProgramError, line: Line) -> None:
    if err.line is None and line is not None:
        err.line = line
        err.feedback = f"line {line}: {err.feedback}"
        err.args = (err.feedback,)


def _short(value: object) -> str:
    text = repr(value) if type(value) in (str, int, float, bool) else type_name(value)
    return text if len(text) <= 60 else text[:57] + "..."


def _callee(node: ast.expr) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return "the called function"


# ---------------------------------------------------------------- the interpreter


class _Interpreter:
    """Evaluates a checked tree. Every node costs one step; sizes are checked by the helpers."""

    def __init__(
        self,
        namespace: Mapping[str, object],
        budget: Budget,
        clock: Callable[[], float],
        local_names: dict[int, frozenset[str]],
    ) -> None:
        self.meter = Meter(budget, clock)
        self.namespace = namespace
        self.ns_cache: dict[str, object] = {}
        self.local_names = local_names

    # -- entry
    def run(self, tree: ast.Module, entry: str) -> object:
        module = _Scope({}, None, None)
        body = [s for s in tree.body if not _is_entry_call(s, entry)]
        self.exec_block(body, module)
        fn = module.vars.get(entry)
        if type(fn) is not SandboxFunction:
            defined = [k for k, v in module.vars.items() if type(v) is SandboxFunction]
            hint = did_you_mean(entry, defined)
            raise MissingEntryError(
                f"the program must define a function `def {entry}():`;"
                + (hint or f" it defines {', '.join(defined) or 'no functions'}")
            )
        assert isinstance(fn, SandboxFunction)
        required = len(fn.params) - len(fn.defaults)
        if required:
            raise ProgramRuntimeError(
                f"{entry}() is called without arguments; remove its parameters "
                f"({', '.join(fn.params[:required])})",
                line=fn.line,
            )
        return self.call_function(fn, [], {}, fn.line)

    # -- statements
    def exec_block(self, body: list[ast.stmt], scope: _Scope) -> object:
        meter = self.meter
        for stmt in body:
            meter.steps += 1
            if not meter.steps & 63:
                meter.tick(stmt.lineno)
            try:
                signal = _STMT[type(stmt)](self, stmt, scope)
            except EventProgramError:
                raise
            except (RecursionError, MemoryError):
                raise BudgetExceededError(
                    "the program nests or recurses too deeply, or uses too much memory",
                    line=stmt.lineno,
                ) from None
            except Exception as err:
                raise ProgramRuntimeError(
                    f"{type(err).__name__}: {err}", line=stmt.lineno
                ) from None
            if signal is not None:
                return signal
        return None

    def s_function(self, node: ast.FunctionDef, scope: _Scope) -> object:
        scope.vars[node.name] = self.make_function(
            node.name, node.args, node.body, None, scope, node
        )
        return None

    def make_function(
        self,
        name: str,
        args: ast.arguments,
        body: list[ast.stmt],
        lambda_body: ast.expr | None,
        scope: _Scope,
        node: ast.AST,
    ) -> SandboxFunction:
        defaults = [self.eval(d, scope) for d in args.defaults]
        params = [a.arg for a in (*args.posonlyargs, *args.args)]
        return SandboxFunction(
            name,
            params,
            defaults,
            body,
            lambda_body,
            scope,
            self.local_names[id(node)],
            getattr(node, "lineno", 0),
        )

    def s_return(self, node: ast.Return, scope: _Scope) -> object:
        return _Return(None if node.value is None else self.eval(node.value, scope))

    def s_assign(self, node: ast.Assign, scope: _Scope) -> object:
        value = self.eval(node.value, scope)
        for target in node.targets:
            self.assign(target, value, scope)
        return None

    def s_annassign(self, node: ast.AnnAssign, scope: _Scope) -> object:
        if node.value is not None:
            self.assign(node.target, self.eval(node.value, scope), scope)
        return None

    def s_augassign(self, node: ast.AugAssign, scope: _Scope) -> object:
        target = node.target
        line = node.lineno
        if isinstance(target, ast.Name):
            current = self.e_name(target, scope)
        elif isinstance(target, ast.Subscript):
            container = self.eval(target.value, scope)
            key = self.eval(target.slice, scope)
            current = self.get_item(container, key, line)
        else:
            raise ForbiddenConstructError(
                "this augmented assignment target is not supported", line=line
            )
        value = self.eval(node.value, scope)
        if type(current) is list and isinstance(node.op, ast.Add):
            items = materialize(value, self.meter, line)
            self.meter.check_len(len(current) + len(items), line, added=len(items))
            current.extend(items)
            result: object = current
        else:
            result = binary(node.op, current, value, self.meter, line)
        if isinstance(target, ast.Name):
            scope.vars[target.id] = result
        else:
            self.set_item(container, key, result, line)
        return None

    def s_expr(self, node: ast.Expr, scope: _Scope) -> object:
        self.eval(node.value, scope)
        return None

    def s_if(self, node: ast.If, scope: _Scope) -> object:
        if self.eval(node.test, scope):
            return self.exec_block(node.body, scope)
        return self.exec_block(node.orelse, scope) if node.orelse else None

    def s_for(self, node: ast.For, scope: _Scope) -> object:
        line = node.lineno
        meter = self.meter
        for item in iter_source(self.eval(node.iter, scope), line):
            meter.loop(line)
            self.assign(node.target, item, scope)
            signal = self.exec_block(node.body, scope)
            if signal is None or signal is _CONTINUE:
                continue
            if signal is _BREAK:
                return None
            return signal
        return self.exec_block(node.orelse, scope) if node.orelse else None

    def s_while(self, node: ast.While, scope: _Scope) -> object:
        line = node.lineno
        meter = self.meter
        while self.eval(node.test, scope):
            meter.loop(line)
            signal = self.exec_block(node.body, scope)
            if signal is None or signal is _CONTINUE:
                continue
            if signal is _BREAK:
                return None
            return signal
        return self.exec_block(node.orelse, scope) if node.orelse else None

    def s_pass(self, node: ast.stmt, scope: _Scope) -> object:
        return None

    def s_break(self, node: ast.stmt, scope: _Scope) -> object:
        return _BREAK

    def s_continue(self, node: ast.stmt, scope: _Scope) -> object:
        return _CONTINUE

    def s_assert(self, node: ast.Assert, scope: _Scope) -> object:
        if not self.eval(node.test, scope):
            detail = ""
            if node.msg is not None:
                detail = ": " + to_text(self.eval(node.msg, scope), self.meter, node.lineno)[:200]
            raise ProgramRuntimeError(
                f"assertion failed: `{ast.unparse(node.test)[:100]}`{detail}", line=node.lineno
            )
        return None

    def s_try(self, node: ast.Try, scope: _Scope) -> object:
        try:
            signal = self.exec_block(node.body, scope)
        except ToolError as err:
            handler = _matching_handler(node.handlers, err)
            if handler is None:
                self.exec_block(node.finalbody, scope)
                raise
            if handler.name:
                scope.vars[handler.name] = err.feedback
            try:
                signal = self.exec_block(handler.body, scope)
            except ToolError:
                self.exec_block(node.finalbody, scope)
                raise
        else:
            if node.orelse:
                try:
                    signal = self.exec_block(node.orelse, scope)
                except ToolError:
                    self.exec_block(node.finalbody, scope)
                    raise
        final = self.exec_block(node.finalbody, scope)
        return final if final is not None else signal

    def s_delete(self, node: ast.Delete, scope: _Scope) -> object:
        for target in node.targets:
            line = node.lineno
            if isinstance(target, ast.Name):
                if scope.vars.pop(target.id, _MISSING) is _MISSING:
                    raise ProgramRuntimeError(
                        f"cannot delete '{target.id}': it is not a local variable here", line=line
                    )
            elif isinstance(target, ast.Subscript):
                container = self.eval(target.value, scope)
                key = self.eval_index(target.slice, scope)
                if type(container) is dict:
                    check_key(key, line)
                elif type(container) is not list:
                    raise ProgramRuntimeError(
                        f"cannot delete items of a '{type_name(container)}'", line=line
                    )
                try:
                    del container[key]  # type: ignore[attr-defined]
                except (KeyError, IndexError, TypeError) as err:
                    raise ProgramRuntimeError(
                        f"cannot delete item {_short(key)}: {type(err).__name__}", line=line
                    ) from None
            else:
                raise ForbiddenConstructError("this 'del' target is not supported", line=line)
        return None

    # -- assignment
    def assign(self, target: ast.expr, value: object, scope: _Scope) -> None:
        t = type(target)
        if t is ast.Name:
            scope.vars[target.id] = value  # type: ignore[attr-defined]
        elif t is ast.Tuple or t is ast.List:
            self.unpack(target.elts, value, scope, target.lineno)  # type: ignore[attr-defined]
        elif t is ast.Subscript:
            container = self.eval(target.value, scope)  # type: ignore[attr-defined]
            self.set_item(container, self.eval_index(target.slice, scope), value, target.lineno)  # type: ignore[attr-defined]
        else:
            raise ForbiddenConstructError(
                "this assignment target is not supported", line=target.lineno
            )

    def unpack(self, elts: list[ast.expr], value: object, scope: _Scope, line: int) -> None:
        items = materialize(value, self.meter, line)
        stars = [i for i, e in enumerate(elts) if isinstance(e, ast.Starred)]
        if len(stars) > 1:
            raise ProgramRuntimeError("only one '*' target is allowed in an assignment", line=line)
        if not stars:
            if len(items) != len(elts):
                raise ProgramRuntimeError(
                    f"cannot unpack {len(items)} values into {len(elts)} names", line=line
                )
            for e, item in zip(elts, items, strict=True):
                self.assign(e, item, scope)
            return
        star = stars[0]
        after = len(elts) - star - 1
        if len(items) < star + after:
            raise ProgramRuntimeError(
                f"cannot unpack {len(items)} values into {len(elts)} names", line=line
            )
        for e, item in zip(elts[:star], items[:star], strict=True):
            self.assign(e, item, scope)
        self.assign(elts[star].value, items[star : len(items) - after], scope)  # type: ignore[attr-defined]
        for e, item in zip(elts[star + 1 :], items[len(items) - after :], strict=True):
            self.assign(e, item, scope)

    def set_item(self, container: object, key: object, value: object, line: Line) -> None:
        t = type(container)
        if t is list:
            lst: list[object] = container  # type: ignore[assignment]
            if type(key) is slice:
                items = materialize(value, self.meter, line)
                self.meter.check_len(len(lst) + len(items), line, added=len(items))
                try:
                    lst[key] = items
                except ValueError as err:
                    raise ProgramRuntimeError(
                        f"slice assignment failed: {err}", line=line
                    ) from None
                return
            if type(key) not in (int, bool):
                raise ProgramRuntimeError(
                    f"list indices must be integers, not '{type_name(key)}'", line=line
                )
            try:
                lst[key] = value  # type: ignore[index]
            except IndexError:
                raise ProgramRuntimeError(
                    f"list index {key} out of range (length {len(lst)})", line=line
                ) from None
        elif t is dict:
            d: dict[object, object] = container  # type: ignore[assignment]
            check_key(key, line)
            if key not in d:
                self.meter.check_len(len(d) + 1, line, added=1)
            d[key] = value
        else:
            raise ProgramRuntimeError(
                f"cannot assign items of a '{t.__name__}' (only lists and dicts)", line=line
            )

    # -- expressions
    def eval(self, node: ast.expr, scope: _Scope) -> object:
        meter = self.meter
        meter.steps += 1
        if not meter.steps & 63:
            meter.tick(node.lineno)
        return _EXPR[type(node)](self, node, scope)

    def e_constant(self, node: ast.Constant, scope: _Scope) -> object:
        return node.value

    def e_name(self, node: ast.Name, scope: _Scope) -> object:
        name = node.id
        s: _Scope | None = scope
        while s is not None:
            value = s.vars.get(name, _MISSING)
            if value is not _MISSING:
                return value
            if s.local_names is not None and name in s.local_names:
                raise ProgramRuntimeError(
                    f"variable '{name}' is used before it is assigned", line=node.lineno
                )
            s = s.parent
        return self.global_name(name, node.lineno)

    def global_name(self, name: str, line: Line) -> object:
        value = self.ns_cache.get(name, _MISSING)
        if value is not _MISSING:
            return value
        if not name.startswith("_") and name in self.namespace:
            value = detach(self.namespace[name])
            self.ns_cache[name] = value
            return value
        builtin = _BUILTIN_FUNCTIONS.get(name)
        if builtin is not None:
            return builtin
        known = [k for k in self.namespace if not k.startswith("_")] + list(BUILTINS)
        raise UnknownNameError(
            f"name '{name}' is not defined;{did_you_mean(name, known, n=1) or ' no such function or variable exists'}",
            line=line,
        )

    def e_binop(self, node: ast.BinOp, scope: _Scope) -> object:
        return binary(
            node.op,
            self.eval(node.left, scope),
            self.eval(node.right, scope),
            self.meter,
            node.lineno,
        )

    def e_unaryop(self, node: ast.UnaryOp, scope: _Scope) -> object:
        return unary(node.op, self.eval(node.operand, scope), self.meter, node.lineno)

    def e_boolop(self, node: ast.BoolOp, scope: _Scope) -> object:
        is_and = isinstance(node.op, ast.And)
        value: object = None
        for operand in node.values:
            value = self.eval(operand, scope)
            if bool(value) != is_and:
                return value
        return value

    def e_compare(self, node: ast.Compare, scope: _Scope) -> object:
        left = self.eval(node.left, scope)
        for op, comparator in zip(node.ops, node.comparators, strict=True):
            right = self.eval(comparator, scope)
            if not compare(op, left, right, self.meter, node.lineno):
                return False
            left = right
        return True

    def e_ifexp(self, node: ast.IfExp, scope: _Scope) -> object:
        return self.eval(node.body if self.eval(node.test, scope) else node.orelse, scope)

    def e_call(self, node: ast.Call, scope: _Scope) -> object:
        line = node.lineno
        fn = self.eval(node.func, scope)
        args: list[object] = []
        for a in node.args:
            if type(a) is ast.Starred:
                args.extend(materialize(self.eval(a.value, scope), self.meter, line))
            else:
                args.append(self.eval(a, scope))
        kwargs: dict[str, object] = {}
        for kw in node.keywords:
            value = self.eval(kw.value, scope)
            if kw.arg is not None:
                kwargs[kw.arg] = value
                continue
            if type(value) is not dict:
                raise ProgramRuntimeError(f"'**' needs a dict, not '{type_name(value)}'", line=line)
            for k, v in value.items():  # type: ignore[attr-defined]
                if type(k) is not str or k.startswith("_"):
                    raise ProgramRuntimeError(
                        "'**' keys must be names not starting with '_'", line=line
                    )
                kwargs[k] = v
        return self.call_value(fn, args, kwargs, line, _callee(node.func))

    def call_value(
        self, fn: object, args: list[object], kwargs: dict[str, object], line: Line, label: str = ""
    ) -> object:
        t = type(fn)
        if t is SandboxFunction:
            return self.call_function(fn, args, kwargs, line)  # type: ignore[arg-type]
        if t is BuiltinFunction:
            return fn.impl(self, args, kwargs, line)  # type: ignore[attr-defined]
        if t is BoundMethod:
            method: BoundMethod = fn  # type: ignore[assignment]
            try:
                return method.impl(self, method.obj, args, kwargs, line)
            except RecursionError:
                raise
            except _METHOD_ERRORS as err:
                raise ProgramRuntimeError(
                    f"{type(method.obj).__name__}.{method.name}() failed: {type(err).__name__}: {err}",
                    line=line,
                ) from None
        if t in OPERAND_TYPES or t is range or not callable(fn):
            raise ProgramRuntimeError(
                f"'{label or type_name(fn)}' is a '{type_name(fn)}', not a function", line=line
            )
        return self.call_external(
            fn, args, kwargs, line, label or getattr(fn, "__name__", type_name(fn))
        )

    def call_external(
        self,
        fn: Callable[..., object],
        args: list[object],
        kwargs: dict[str, object],
        line: Line,
        label: str,
    ) -> object:
        token = errors.PROGRAM_LINE.set(line)
        try:
            result = fn(*args, **kwargs)
        except EventProgramError as err:
            _add_line(err, line)
            raise
        except (RecursionError, MemoryError):
            raise BudgetExceededError(f"{label}() ran out of stack or memory", line=line) from None
        except (Exception, SystemExit, KeyboardInterrupt) as err:
            message = f"{label}() failed: {type(err).__name__}: {err}"
            if isinstance(err, TypeError):
                with contextlib.suppress(TypeError, ValueError):
                    message += f" (expected {label}{inspect.signature(fn)})"
            raise ProgramRuntimeError(message, line=line) from None
        finally:
            errors.PROGRAM_LINE.reset(token)
        self.meter.check_time(line)
        return detach(result)

    def call_function(
        self, fn: SandboxFunction, args: list[object], kwargs: dict[str, object], line: Line
    ) -> object:
        meter = self.meter
        if meter.depth >= meter.budget.recursion_depth:
            raise BudgetExceededError(
                f"calls nest more than {meter.budget.recursion_depth} deep (runaway recursion in {fn.name}()?)",
                line=line,
            )
        params = fn.params
        if len(args) > len(params):
            raise ProgramRuntimeError(
                f"{fn.name}() takes {len(params)} arguments but {len(args)} were given", line=line
            )
        bound = dict(zip(params, args, strict=False))
        for key, value in kwargs.items():
            if key not in params:
                raise ProgramRuntimeError(
                    f"{fn.name}() got an unexpected keyword argument '{key}';{did_you_mean(key, params) or ' parameters: ' + ', '.join(params)}",
                    line=line,
                )
            if key in bound:
                raise ProgramRuntimeError(f"{fn.name}() got multiple values for '{key}'", line=line)
            bound[key] = value
        if len(bound) < len(params):
            first_default = len(params) - len(fn.defaults)
            for i, p in enumerate(params):
                if p not in bound:
                    if i < first_default:
                        raise ProgramRuntimeError(
                            f"{fn.name}() is missing the argument '{p}'", line=line
                        )
                    bound[p] = fn.defaults[i - first_default]
        scope = _Scope(bound, fn.closure, fn.local_names)
        meter.depth += 1
        try:
            if fn.lambda_body is not None:
                return self.eval(fn.lambda_body, scope)
            signal = self.exec_block(fn.body, scope)
        finally:
            meter.depth -= 1
        return signal.value if type(signal) is _Return else None

    def e_lambda(self, node: ast.Lambda, scope: _Scope) -> object:
        return self.make_function("<lambda>", node.args, [], node.body, scope, node)

    def e_namedexpr(self, node: ast.NamedExpr, scope: _Scope) -> object:
        value = self.eval(node.value, scope)
        s = scope
        while s.local_names is None and s.parent is not None:
            s = s.parent
        s.vars[node.target.id] = value
        return value

    def e_attribute(self, node: ast.Attribute, scope: _Scope) -> object:
        return self.get_attribute(self.eval(node.value, scope), node.attr, node.lineno)

    def get_attribute(self, obj: object, name: str, line: Line) -> object:
        t = type(obj)
        if name.startswith("_"):
            raise ForbiddenConstructError(
                f"attributes starting with '_' are not allowed ('.{name}')", line=line
            )
        methods = METHODS.get(t)
        if methods is not None:
            impl = methods.get(name)
            if impl is not None:
                return BoundMethod(obj, name, impl)
            allowed: frozenset[str] | set[str] | dict[str, MethodImpl] = methods
        else:
            declared = getattr(t, "sandbox_attributes", None) if t not in _INTERNAL else None
            allowed = declared if isinstance(declared, frozenset | set) else frozenset()
            if name in allowed:
                try:
                    return detach(getattr(obj, name))
                except EventProgramError as err:
                    _add_line(err, line)
                    raise
                except (AttributeError, TypeError, ValueError) as err:
                    raise ProgramRuntimeError(
                        f"reading '.{name}' failed: {err}", line=line
                    ) from None
        if hasattr(t, name):
            raise ForbiddenConstructError(
                f"'{t.__name__}.{name}' is not available in event programs"
                + (" (use an f-string)" if name in ("format", "format_map") else ""),
                line=line,
            )
        public = sorted(k for k in allowed if not k.startswith("_"))
        hint = did_you_mean(name, public, n=1) or (
            f" available: {', '.join(public[:12])}" if public else " it has no usable attributes"
        )
        raise ProgramRuntimeError(
            f"'{t.__name__}' object has no attribute '{name}';{hint}", line=line
        )

    def eval_index(self, node: ast.expr, scope: _Scope) -> object:
        if not isinstance(node, ast.Slice):
            return self.eval(node, scope)
        parts = []
        for part in (node.lower, node.upper, node.step):
            value = None if part is None else self.eval(part, scope)
            if value is not None and type(value) not in (int, bool):
                raise ProgramRuntimeError(
                    f"slice bounds must be integers or None, not '{type_name(value)}'",
                    line=node.lineno,
                )
            parts.append(value)
        return slice(*parts)

    def e_subscript(self, node: ast.Subscript, scope: _Scope) -> object:
        container = self.eval(node.value, scope)
        return self.get_item(container, self.eval_index(node.slice, scope), node.lineno)

    def get_item(self, container: object, key: object, line: Line) -> object:
        t = type(container)
        if t is dict:
            check_key(key, line)
            try:
                return container[key]  # type: ignore[index]
            except KeyError:
                keys = [k for k in container if type(k) is str]  # type: ignore[attr-defined]
                hint = did_you_mean(key, keys) if type(key) is str else ""
                raise ProgramRuntimeError(
                    f"key {_short(key)} is not in the dict;{hint or ' use d.get(key) to allow missing keys'}",
                    line=line,
                ) from None
        if t in (list, tuple, str, range):
            if type(key) is slice:
                result = container[key]  # type: ignore[index]
                self.meter.allocate(len(result), line)
                return result
            if type(key) not in (int, bool):
                raise ProgramRuntimeError(
                    f"{t.__name__} indices must be integers, not '{type_name(key)}'", line=line
                )
            try:
                return container[key]  # type: ignore[index]
            except IndexError:
                raise ProgramRuntimeError(
                    f"{t.__name__} index {key} out of range (length {len(container)})", line=line
                ) from None  # type: ignore[arg-type]
        declared = getattr(t, "sandbox_operators", None) if t not in _INTERNAL else None
        if isinstance(declared, frozenset | set) and "[]" in declared:
            try:
                return detach(container[key])  # type: ignore[index]
            except EventProgramError as err:
                _add_line(err, line)
                raise
        raise ProgramRuntimeError(f"a '{t.__name__}' cannot be indexed with [...]", line=line)

    def collect(self, elts: list[ast.expr], scope: _Scope, line: int) -> list[object]:
        out: list[object] = []
        for e in elts:
            if isinstance(e, ast.Starred):
                out.extend(materialize(self.eval(e.value, scope), self.meter, line))
            else:
                out.append(self.eval(e, scope))
        self.meter.check_len(len(out), line)
        return out

    def e_list(self, node: ast.List, scope: _Scope) -> object:
        return self.collect(node.elts, scope, node.lineno)

    def e_tuple(self, node: ast.Tuple, scope: _Scope) -> object:
        return tuple(self.collect(node.elts, scope, node.lineno))

    def e_set(self, node: ast.Set, scope: _Scope) -> object:
        items = self.collect(node.elts, scope, node.lineno)
        for item in items:
            check_key(item, node.lineno)
        check_hash_spread(items, self.meter, node.lineno)
        return set(items)

    def e_dict(self, node: ast.Dict, scope: _Scope) -> object:
        out: dict[object, object] = {}
        line = node.lineno
        for k, v in zip(node.keys, node.values, strict=True):
            if k is None:
                other = self.eval(v, scope)
                if type(other) is not dict:
                    raise ProgramRuntimeError(
                        f"'**' needs a dict, not '{type_name(other)}'", line=line
                    )
                self.meter.check_len(len(out) + len(other), line)  # type: ignore[arg-type]
                check_hash_spread([*out, *other], self.meter, line)  # type: ignore[misc]
                out.update(other)  # type: ignore[call-overload]
                continue
            key = self.eval(k, scope)
            check_key(key, line)
            out[key] = self.eval(v, scope)
        self.meter.check_len(len(out), line)
        return out

    def comprehension(
        self,
        node: ast.ListComp | ast.SetComp | ast.DictComp | ast.GeneratorExp,
        scope: _Scope,
        emit: Callable[[_Scope], None],
    ) -> None:
        inner = _Scope({}, scope, None)
        self.generate(node.generators, 0, inner, emit, node.lineno)

    def generate(
        self,
        gens: list[ast.comprehension],
        index: int,
        scope: _Scope,
        emit: Callable[[_Scope], None],
        line: int,
    ) -> None:
        gen = gens[index]
        meter = self.meter
        for item in iter_source(self.eval(gen.iter, scope), line):
            meter.loop(line)
            self.assign(gen.target, item, scope)
            if all(self.eval(cond, scope) for cond in gen.ifs):
                if index + 1 < len(gens):
                    self.generate(gens, index + 1, scope, emit, line)
                else:
                    emit(scope)

    def e_listcomp(self, node: ast.ListComp | ast.GeneratorExp, scope: _Scope) -> object:
        out: list[object] = []
        meter = self.meter

        def emit(inner: _Scope) -> None:
            meter.check_len(len(out) + 1, node.lineno, added=1)
            out.append(self.eval(node.elt, inner))

        self.comprehension(node, scope, emit)
        return out

    def e_setcomp(self, node: ast.SetComp, scope: _Scope) -> object:
        out: set[object] = set()

        def emit(inner: _Scope) -> None:
            item = self.eval(node.elt, inner)
            check_key(item, node.lineno)
            self.meter.check_len(len(out) + 1, node.lineno, added=1)
            out.add(item)

        self.comprehension(node, scope, emit)
        return out

    def e_dictcomp(self, node: ast.DictComp, scope: _Scope) -> object:
        out: dict[object, object] = {}

        def emit(inner: _Scope) -> None:
            key = self.eval(node.key, inner)
            check_key(key, node.lineno)
            self.meter.check_len(len(out) + 1, node.lineno, added=1)
            out[key] = self.eval(node.value, inner)

        self.comprehension(node, scope, emit)
        return out

    def e_joinedstr(self, node: ast.JoinedStr, scope: _Scope) -> object:
        parts: list[str] = []
        for part in node.values:
            if isinstance(part, ast.FormattedValue):
                parts.append(self.formatted(part, scope))
            else:
                parts.append(self.eval(part, scope))  # type: ignore[arg-type]
        self.meter.check_str(sum(map(len, parts)), node.lineno)
        return "".join(parts)

    def formatted(self, node: ast.FormattedValue, scope: _Scope) -> str:
        line = node.lineno
        value = self.eval(node.value, scope)
        conversion = {115: "s", 114: "r", 97: "a"}.get(node.conversion)
        if conversion is not None:
            value = to_text(value, self.meter, line, conversion)
        if node.format_spec is None:
            return to_text(value, self.meter, line)
        spec = self.e_joinedstr(node.format_spec, scope)  # type: ignore[arg-type]
        return format_value(value, spec, self.meter, line)  # type: ignore[arg-type]

    def e_formattedvalue(self, node: ast.FormattedValue, scope: _Scope) -> object:
        return self.formatted(node, scope)

    def e_starred(self, node: ast.Starred, scope: _Scope) -> object:
        raise ForbiddenConstructError("'*' is not allowed here", line=node.lineno)


def _is_entry_call(stmt: ast.stmt, entry: str) -> bool:
    """A top-level `parse_event()` line: skipped, since the sandbox calls the entry itself."""
    return (
        isinstance(stmt, ast.Expr)
        and isinstance(stmt.value, ast.Call)
        and isinstance(stmt.value.func, ast.Name)
        and stmt.value.func.id == entry
        and not stmt.value.args
        and not stmt.value.keywords
    )


def _matching_handler(
    handlers: list[ast.ExceptHandler], err: ToolError
) -> ast.ExceptHandler | None:
    for handler in handlers:
        if handler.type is None:
            return handler
        names = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
        for n in names:
            if isinstance(n, ast.Name) and isinstance(err, _CATCHABLE[n.id]):
                return handler
    return None


_I = _Interpreter
_STMT: dict[type[ast.AST], Callable[[_Interpreter, ast.stmt, _Scope], object]] = {  # type: ignore[dict-item]
    ast.FunctionDef: _I.s_function,
    ast.Return: _I.s_return,
    ast.Assign: _I.s_assign,
    ast.AnnAssign: _I.s_annassign,
    ast.AugAssign: _I.s_augassign,
    ast.Expr: _I.s_expr,
    ast.If: _I.s_if,
    ast.For: _I.s_for,
    ast.While: _I.s_while,
    ast.Pass: _I.s_pass,
    ast.Break: _I.s_break,
    ast.Continue: _I.s_continue,
    ast.Assert: _I.s_assert,
    ast.Try: _I.s_try,
    ast.Delete: _I.s_delete,
}
_EXPR: dict[type[ast.AST], Callable[[_Interpreter, ast.expr, _Scope], object]] = {  # type: ignore[dict-item]
    ast.Constant: _I.e_constant,
    ast.Name: _I.e_name,
    ast.BinOp: _I.e_binop,
    ast.UnaryOp: _I.e_unaryop,
    ast.BoolOp: _I.e_boolop,
    ast.Compare: _I.e_compare,
    ast.IfExp: _I.e_ifexp,
    ast.Call: _I.e_call,
    ast.Lambda: _I.e_lambda,
    ast.NamedExpr: _I.e_namedexpr,
    ast.Attribute: _I.e_attribute,
    ast.Subscript: _I.e_subscript,
    ast.List: _I.e_list,
    ast.Tuple: _I.e_tuple,
    ast.Set: _I.e_set,
    ast.Dict: _I.e_dict,
    ast.ListComp: _I.e_listcomp,
    ast.GeneratorExp: _I.e_listcomp,
    ast.SetComp: _I.e_setcomp,
    ast.DictComp: _I.e_dictcomp,
    ast.JoinedStr: _I.e_joinedstr,
    ast.FormattedValue: _I.e_formattedvalue,
    ast.Starred: _I.e_starred,
}

"""The interpreter: evaluates a checked event program, one tree node at a time.

``Interpreter`` runs the entry function and evaluates expressions (names, operators, calls,
attributes, subscripts, displays, comprehensions, f-strings); its base ``Statements`` runs
statements. Each statement and expression node costs one interpreter step (the ``Meter``
checks steps and the injected clock every 64 steps); every value the program builds goes
through the size-checking helpers of ``boundary``, ``operators``, ``builtin_functions``,
``methods`` and ``access``. Nodes are dispatched by exact type through ``_STMT`` / ``_EXPR``,
which hold only the node types the checker allows. Program calls use about 15 Python frames
per level: a caller already near Python's recursion limit gets ``BudgetExceededError``
earlier.
"""

from __future__ import annotations

import ast
from collections.abc import Callable, Mapping
from typing import TypeAlias, TypeVar, cast

from storyteller.tools.sandbox.access import call_external, get_attribute, get_item
from storyteller.tools.sandbox.boundary import (
    OPERAND_TYPES,
    check_key,
    detach,
    format_value,
    iter_source,
    materialize,
    range_item_bytes,
    to_text,
    type_name,
)
from storyteller.tools.sandbox.budget import DICT_ITEM_BYTES, SET_ITEM_BYTES, Budget, Meter
from storyteller.tools.sandbox.builtin_functions import BUILTINS
from storyteller.tools.sandbox.errors import (
    BudgetExceededError,
    ForbiddenConstructError,
    Line,
    MissingEntryError,
    ProgramRuntimeError,
    UnknownNameError,
    describe,
)
from storyteller.tools.sandbox.operators import binary, check_hash_spread, compare, unary
from storyteller.tools.sandbox.statements import Statements
from storyteller.tools.sandbox.values import (
    BUILTIN_FUNCTIONS,
    MISSING,
    BoundMethod,
    BuiltinFunction,
    Return,
    SandboxFunction,
    Scope,
)

_METHOD_ERRORS = (TypeError, ValueError, IndexError, KeyError, AttributeError, OverflowError)


def _callee(node: ast.expr) -> str:
    if isinstance(node, ast.Name):
        return node.id
    if isinstance(node, ast.Attribute):
        return node.attr
    return "the called function"


class Interpreter(Statements):
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
        module = Scope({}, None, None)
        body = [s for s in tree.body if not _is_entry_call(s, entry)]
        self.exec_block(body, module)
        fn = module.vars.get(entry)
        if type(fn) is not SandboxFunction:
            defined = [k for k, v in module.vars.items() if type(v) is SandboxFunction]
            hint = self.meter.suggest(entry, defined, None)
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

    # -- expressions
    def eval(self, node: ast.expr, scope: Scope) -> object:
        meter = self.meter
        meter.steps += 1
        if not meter.steps & 63:
            meter.tick(node.lineno)
        return _EXPR[type(node)](self, node, scope)

    def e_constant(self, node: ast.Constant, scope: Scope) -> object:
        return node.value

    def e_name(self, node: ast.Name, scope: Scope) -> object:
        name = node.id
        s: Scope | None = scope
        while s is not None:
            value = s.vars.get(name, MISSING)
            if value is not MISSING:
                return value
            if s.local_names is not None and name in s.local_names:
                raise ProgramRuntimeError(
                    f"variable '{name}' is used before it is assigned", line=node.lineno
                )
            s = s.parent
        return self.global_name(name, node.lineno)

    def global_name(self, name: str, line: Line) -> object:
        value = self.ns_cache.get(name, MISSING)
        if value is not MISSING:
            return value
        if not name.startswith("_") and name in self.namespace:
            value = detach(self.namespace[name])
            self.ns_cache[name] = value
            return value
        builtin = BUILTIN_FUNCTIONS.get(name)
        if builtin is not None:
            return builtin
        known = [k for k in self.namespace if not k.startswith("_")] + list(BUILTINS)
        hint = self.meter.suggest(name, known, line, n=1)
        raise UnknownNameError(
            f"name '{name}' is not defined;{hint or ' no such function or variable exists'}",
            line=line,
        )

    def e_binop(self, node: ast.BinOp, scope: Scope) -> object:
        return binary(
            node.op,
            self.eval(node.left, scope),
            self.eval(node.right, scope),
            self.meter,
            node.lineno,
        )

    def e_unaryop(self, node: ast.UnaryOp, scope: Scope) -> object:
        return unary(node.op, self.eval(node.operand, scope), self.meter, node.lineno)

    def e_boolop(self, node: ast.BoolOp, scope: Scope) -> object:
        is_and = isinstance(node.op, ast.And)
        value: object = None
        for operand in node.values:
            value = self.eval(operand, scope)
            if bool(value) != is_and:
                return value
        return value

    def e_compare(self, node: ast.Compare, scope: Scope) -> object:
        left = self.eval(node.left, scope)
        for op, comparator in zip(node.ops, node.comparators, strict=True):
            right = self.eval(comparator, scope)
            if not compare(op, left, right, self.meter, node.lineno):
                return False
            left = right
        return True

    def e_ifexp(self, node: ast.IfExp, scope: Scope) -> object:
        return self.eval(node.body if self.eval(node.test, scope) else node.orelse, scope)

    def e_call(self, node: ast.Call, scope: Scope) -> object:
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
            for k, v in value.items():
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
        if type(fn) is SandboxFunction:
            return self.call_function(fn, args, kwargs, line)
        if type(fn) is BuiltinFunction:
            return fn.impl(self, args, kwargs, line)
        if type(fn) is BoundMethod:
            method = fn
            try:
                return method.impl(self, method.obj, args, kwargs, line)
            except RecursionError:
                raise
            except _METHOD_ERRORS as err:
                raise ProgramRuntimeError(
                    f"{type(method.obj).__name__}.{method.name}() failed: {describe(err)}",
                    line=line,
                ) from None
        if t in OPERAND_TYPES or t is range or not callable(fn):
            raise ProgramRuntimeError(
                f"'{label or type_name(fn)}' is a '{type_name(fn)}', not a function", line=line
            )
        return call_external(
            fn, args, kwargs, self.meter, line, label or getattr(fn, "__name__", type_name(fn))
        )

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
                hint = meter.suggest(key, params, line)
                raise ProgramRuntimeError(
                    f"{fn.name}() got an unexpected keyword argument '{key}';{hint or ' parameters: ' + ', '.join(params)}",
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
        scope = Scope(bound, fn.closure, fn.local_names)
        meter.depth += 1
        try:
            if fn.lambda_body is not None:
                return self.eval(fn.lambda_body, scope)
            signal = self.exec_block(fn.body, scope)
        finally:
            meter.depth -= 1
        return signal.value if type(signal) is Return else None

    def e_lambda(self, node: ast.Lambda, scope: Scope) -> object:
        return self.make_function("<lambda>", node.args, [], node.body, scope, node)

    def e_namedexpr(self, node: ast.NamedExpr, scope: Scope) -> object:
        value = self.eval(node.value, scope)
        s = scope
        while s.local_names is None and s.parent is not None:
            s = s.parent
        s.vars[node.target.id] = value
        return value

    def e_attribute(self, node: ast.Attribute, scope: Scope) -> object:
        return get_attribute(self.eval(node.value, scope), node.attr, node.lineno)

    def eval_index(self, node: ast.expr, scope: Scope) -> object:
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

    def e_subscript(self, node: ast.Subscript, scope: Scope) -> object:
        container = self.eval(node.value, scope)
        return get_item(container, self.eval_index(node.slice, scope), self.meter, node.lineno)

    def collect(self, elts: list[ast.expr], scope: Scope, line: int) -> list[object]:
        out: list[object] = []
        for e in elts:
            if isinstance(e, ast.Starred):
                out.extend(materialize(self.eval(e.value, scope), self.meter, line))
            else:
                out.append(self.eval(e, scope))
        self.meter.check_len(len(out), line)
        return out

    def e_list(self, node: ast.List, scope: Scope) -> object:
        return self.collect(node.elts, scope, node.lineno)

    def e_tuple(self, node: ast.Tuple, scope: Scope) -> object:
        return tuple(self.collect(node.elts, scope, node.lineno))

    def e_set(self, node: ast.Set, scope: Scope) -> object:
        items = self.collect(node.elts, scope, node.lineno)
        for item in items:
            check_key(item, node.lineno)
        check_hash_spread(items, self.meter, node.lineno)
        return set(items)

    def e_dict(self, node: ast.Dict, scope: Scope) -> object:
        out: dict[object, object] = {}
        line = node.lineno
        for k, v in zip(node.keys, node.values, strict=True):
            if k is None:
                other = self.eval(v, scope)
                if type(other) is not dict:
                    raise ProgramRuntimeError(
                        f"'**' needs a dict, not '{type_name(other)}'", line=line
                    )
                self.meter.check_len(len(out) + len(other), line, item_bytes=DICT_ITEM_BYTES)
                check_hash_spread([*out, *other], self.meter, line)
                out.update(other)
                continue
            key = self.eval(k, scope)
            check_key(key, line)
            out[key] = self.eval(v, scope)
        self.meter.check_len(len(out), line, item_bytes=DICT_ITEM_BYTES)
        return out

    def comprehension(
        self,
        node: ast.ListComp | ast.SetComp | ast.DictComp | ast.GeneratorExp,
        scope: Scope,
        emit: Callable[[Scope], None],
    ) -> None:
        inner = Scope({}, scope, None)
        self.generate(node.generators, 0, inner, emit, node.lineno)

    def generate(
        self,
        gens: list[ast.comprehension],
        index: int,
        scope: Scope,
        emit: Callable[[Scope], None],
        line: int,
    ) -> None:
        gen = gens[index]
        meter = self.meter
        source = iter_source(self.eval(gen.iter, scope), line)
        item_bytes = range_item_bytes(source)
        for item in source:
            meter.loop(line)
            if item_bytes:
                meter.charge(item_bytes, line)
            self.assign(gen.target, item, scope)
            if all(self.eval(cond, scope) for cond in gen.ifs):
                if index + 1 < len(gens):
                    self.generate(gens, index + 1, scope, emit, line)
                else:
                    emit(scope)

    def e_listcomp(self, node: ast.ListComp | ast.GeneratorExp, scope: Scope) -> object:
        out: list[object] = []
        meter = self.meter

        def emit(inner: Scope) -> None:
            meter.check_len(len(out) + 1, node.lineno, added=1)
            out.append(self.eval(node.elt, inner))

        self.comprehension(node, scope, emit)
        return out

    def e_setcomp(self, node: ast.SetComp, scope: Scope) -> object:
        out: set[object] = set()

        def emit(inner: Scope) -> None:
            item = self.eval(node.elt, inner)
            check_key(item, node.lineno)
            self.meter.check_len(len(out) + 1, node.lineno, added=1, item_bytes=SET_ITEM_BYTES)
            out.add(item)

        self.comprehension(node, scope, emit)
        return out

    def e_dictcomp(self, node: ast.DictComp, scope: Scope) -> object:
        out: dict[object, object] = {}

        def emit(inner: Scope) -> None:
            key = self.eval(node.key, inner)
            check_key(key, node.lineno)
            self.meter.check_len(len(out) + 1, node.lineno, added=1, item_bytes=DICT_ITEM_BYTES)
            out[key] = self.eval(node.value, inner)

        self.comprehension(node, scope, emit)
        return out

    def e_joinedstr(self, node: ast.JoinedStr, scope: Scope) -> str:
        parts: list[str] = []
        for part in node.values:
            if isinstance(part, ast.FormattedValue):
                parts.append(self.formatted(part, scope))
            else:
                parts.append(cast(str, self.eval(part, scope)))  # f-string text is a str Constant
        self.meter.check_str(sum(map(len, parts)), node.lineno)
        return "".join(parts)

    def formatted(self, node: ast.FormattedValue, scope: Scope) -> str:
        line = node.lineno
        value = self.eval(node.value, scope)
        conversion = {115: "s", 114: "r", 97: "a"}.get(node.conversion)
        if conversion is not None:
            value = to_text(value, self.meter, line, conversion)
        if not isinstance(node.format_spec, ast.JoinedStr):  # ast gives a spec as a JoinedStr
            return to_text(value, self.meter, line)
        spec = self.e_joinedstr(node.format_spec, scope)
        return format_value(value, spec, self.meter, line)

    def e_formattedvalue(self, node: ast.FormattedValue, scope: Scope) -> object:
        return self.formatted(node, scope)

    def e_starred(self, node: ast.Starred, scope: Scope) -> object:
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


_E = TypeVar("_E", bound=ast.expr)
ExprHandler: TypeAlias = Callable[[Interpreter, ast.expr, Scope], object]


def _expr(
    node_type: type[_E], handler: Callable[[Interpreter, _E, Scope], object]
) -> tuple[type[ast.AST], ExprHandler]:
    """An ``_EXPR`` entry: ``eval`` looks handlers up by the node's exact type, so the
    handler of ``node_type`` only ever receives a ``node_type``."""
    return node_type, cast(ExprHandler, handler)


_I = Interpreter
_EXPR: dict[type[ast.AST], ExprHandler] = dict(
    [
        _expr(ast.Constant, _I.e_constant),
        _expr(ast.Name, _I.e_name),
        _expr(ast.BinOp, _I.e_binop),
        _expr(ast.UnaryOp, _I.e_unaryop),
        _expr(ast.BoolOp, _I.e_boolop),
        _expr(ast.Compare, _I.e_compare),
        _expr(ast.IfExp, _I.e_ifexp),
        _expr(ast.Call, _I.e_call),
        _expr(ast.Lambda, _I.e_lambda),
        _expr(ast.NamedExpr, _I.e_namedexpr),
        _expr(ast.Attribute, _I.e_attribute),
        _expr(ast.Subscript, _I.e_subscript),
        _expr(ast.List, _I.e_list),
        _expr(ast.Tuple, _I.e_tuple),
        _expr(ast.Set, _I.e_set),
        _expr(ast.Dict, _I.e_dict),
        _expr(ast.ListComp, _I.e_listcomp),
        _expr(ast.GeneratorExp, _I.e_listcomp),
        _expr(ast.SetComp, _I.e_setcomp),
        _expr(ast.DictComp, _I.e_dictcomp),
        _expr(ast.JoinedStr, _I.e_joinedstr),
        _expr(ast.FormattedValue, _I.e_formattedvalue),
        _expr(ast.Starred, _I.e_starred),
    ]
)

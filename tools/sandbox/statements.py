"""Statements of event programs: blocks, assignment, ``if`` / ``for`` / ``while``, ``try``,
``del``, ``def``, ``return``, ``assert``.

``Statements`` is the statement half of the interpreter (``Interpreter`` adds expressions).
Each statement costs one step; ``exec_block`` runs a block and returns its control-flow
signal (``None``, ``Return``, ``BREAK`` or ``CONTINUE``). Anything other than an
``EventProgramError`` that escapes a statement becomes ``ProgramRuntimeError`` on its line
(``BudgetExceededError`` for stack or memory exhaustion). ``try`` catches tool errors only.
"""

from __future__ import annotations

import ast
from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Protocol, TypeAlias, TypeVar, cast

from storyteller.tools.errors import EventProgramError, ToolError
from storyteller.tools.sandbox.access import get_item, set_item, short_repr
from storyteller.tools.sandbox.boundary import (
    check_key,
    iter_source,
    materialize,
    range_item_bytes,
    to_text,
    type_name,
)
from storyteller.tools.sandbox.budget import Meter
from storyteller.tools.sandbox.checker import CATCHABLE
from storyteller.tools.sandbox.errors import (
    BudgetExceededError,
    ForbiddenConstructError,
    ProgramRuntimeError,
    describe,
)
from storyteller.tools.sandbox.operators import binary
from storyteller.tools.sandbox.values import BREAK, CONTINUE, MISSING, Return, SandboxFunction, Scope


class _Deletable(Protocol):
    """A list or a dict as ``del container[key]`` sees it (a bad key raises ``TypeError``)."""

    def __delitem__(self, key: object, /) -> None: ...


def _matching_handler(
    handlers: list[ast.ExceptHandler], err: ToolError
) -> ast.ExceptHandler | None:
    for handler in handlers:
        if handler.type is None:
            return handler
        names = handler.type.elts if isinstance(handler.type, ast.Tuple) else [handler.type]
        for n in names:
            if isinstance(n, ast.Name) and isinstance(err, CATCHABLE[n.id]):
                return handler
    return None


class Statements(ABC):
    """Runs statements; the expression side (``eval``...) is ``Interpreter``'s."""

    meter: Meter
    local_names: dict[int, frozenset[str]]
    """Each function's local names, keyed by the id of its checked ``def`` / ``lambda`` node."""

    @abstractmethod
    def eval(self, node: ast.expr, scope: Scope) -> object: ...

    @abstractmethod
    def eval_index(self, node: ast.expr, scope: Scope) -> object: ...

    @abstractmethod
    def e_name(self, node: ast.Name, scope: Scope) -> object: ...

    # -- statements
    def exec_block(self, body: list[ast.stmt], scope: Scope) -> object:
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
                raise ProgramRuntimeError(describe(err), line=stmt.lineno) from None
            if signal is not None:
                return signal
        return None

    def s_function(self, node: ast.FunctionDef, scope: Scope) -> object:
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
        scope: Scope,
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

    def s_return(self, node: ast.Return, scope: Scope) -> object:
        return Return(None if node.value is None else self.eval(node.value, scope))

    def s_assign(self, node: ast.Assign, scope: Scope) -> object:
        value = self.eval(node.value, scope)
        for target in node.targets:
            self.assign(target, value, scope)
        return None

    def s_annassign(self, node: ast.AnnAssign, scope: Scope) -> object:
        if node.value is not None:
            self.assign(node.target, self.eval(node.value, scope), scope)
        return None

    def s_augassign(self, node: ast.AugAssign, scope: Scope) -> object:
        target = node.target
        line = node.lineno
        if isinstance(target, ast.Name):
            current = self.e_name(target, scope)
        elif isinstance(target, ast.Subscript):
            container = self.eval(target.value, scope)
            key = self.eval_index(target.slice, scope)
            current = get_item(container, key, self.meter, line)
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
            set_item(container, key, result, self.meter, line)
        return None

    def s_expr(self, node: ast.Expr, scope: Scope) -> object:
        self.eval(node.value, scope)
        return None

    def s_if(self, node: ast.If, scope: Scope) -> object:
        if self.eval(node.test, scope):
            return self.exec_block(node.body, scope)
        return self.exec_block(node.orelse, scope) if node.orelse else None

    def s_for(self, node: ast.For, scope: Scope) -> object:
        line = node.lineno
        meter = self.meter
        source = iter_source(self.eval(node.iter, scope), line)
        item_bytes = range_item_bytes(source)
        for item in source:
            meter.loop(line)
            if item_bytes:
                meter.charge(item_bytes, line)
            self.assign(node.target, item, scope)
            signal = self.exec_block(node.body, scope)
            if signal is None or signal is CONTINUE:
                continue
            if signal is BREAK:
                return None
            return signal
        return self.exec_block(node.orelse, scope) if node.orelse else None

    def s_while(self, node: ast.While, scope: Scope) -> object:
        line = node.lineno
        meter = self.meter
        while self.eval(node.test, scope):
            meter.loop(line)
            signal = self.exec_block(node.body, scope)
            if signal is None or signal is CONTINUE:
                continue
            if signal is BREAK:
                return None
            return signal
        return self.exec_block(node.orelse, scope) if node.orelse else None

    def s_pass(self, node: ast.stmt, scope: Scope) -> object:
        return None

    def s_break(self, node: ast.stmt, scope: Scope) -> object:
        return BREAK

    def s_continue(self, node: ast.stmt, scope: Scope) -> object:
        return CONTINUE

    def s_assert(self, node: ast.Assert, scope: Scope) -> object:
        if not self.eval(node.test, scope):
            detail = ""
            if node.msg is not None:
                detail = ": " + to_text(self.eval(node.msg, scope), self.meter, node.lineno)[:200]
            raise ProgramRuntimeError(
                f"assertion failed: `{ast.unparse(node.test)[:100]}`{detail}", line=node.lineno
            )
        return None

    def s_try(self, node: ast.Try, scope: Scope) -> object:
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

    def s_delete(self, node: ast.Delete, scope: Scope) -> object:
        for target in node.targets:
            line = node.lineno
            if isinstance(target, ast.Name):
                if scope.vars.pop(target.id, MISSING) is MISSING:
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
                    del cast(_Deletable, container)[key]
                except (KeyError, IndexError, TypeError) as err:
                    raise ProgramRuntimeError(
                        f"cannot delete item {short_repr(key)}: {type(err).__name__}", line=line
                    ) from None
            else:
                raise ForbiddenConstructError("this 'del' target is not supported", line=line)
        return None

    # -- assignment
    def assign(self, target: ast.expr, value: object, scope: Scope) -> None:
        if isinstance(target, ast.Name):
            scope.vars[target.id] = value
        elif isinstance(target, ast.Tuple | ast.List):
            self.unpack(target.elts, value, scope, target.lineno)
        elif isinstance(target, ast.Subscript):
            container = self.eval(target.value, scope)
            key = self.eval_index(target.slice, scope)
            set_item(container, key, value, self.meter, target.lineno)
        else:
            raise ForbiddenConstructError(
                "this assignment target is not supported", line=target.lineno
            )

    def unpack(self, elts: list[ast.expr], value: object, scope: Scope, line: int) -> None:
        items = materialize(value, self.meter, line)
        stars = [(i, e) for i, e in enumerate(elts) if isinstance(e, ast.Starred)]
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
        star, starred = stars[0]
        after = len(elts) - star - 1
        if len(items) < star + after:
            raise ProgramRuntimeError(
                f"cannot unpack {len(items)} values into {len(elts)} names", line=line
            )
        for e, item in zip(elts[:star], items[:star], strict=True):
            self.assign(e, item, scope)
        self.assign(starred.value, items[star : len(items) - after], scope)
        for e, item in zip(elts[star + 1 :], items[len(items) - after :], strict=True):
            self.assign(e, item, scope)


_S = TypeVar("_S", bound=ast.stmt)
StmtHandler: TypeAlias = Callable[[Statements, ast.stmt, Scope], object]


def _stmt(
    node_type: type[_S], handler: Callable[[Statements, _S, Scope], object]
) -> tuple[type[ast.AST], StmtHandler]:
    """A ``_STMT`` entry: ``exec_block`` looks handlers up by the node's exact type, so the
    handler of ``node_type`` only ever receives a ``node_type``."""
    return node_type, cast(StmtHandler, handler)


_STMT: dict[type[ast.AST], StmtHandler] = dict(
    [
        _stmt(ast.FunctionDef, Statements.s_function),
        _stmt(ast.Return, Statements.s_return),
        _stmt(ast.Assign, Statements.s_assign),
        _stmt(ast.AnnAssign, Statements.s_annassign),
        _stmt(ast.AugAssign, Statements.s_augassign),
        _stmt(ast.Expr, Statements.s_expr),
        _stmt(ast.If, Statements.s_if),
        _stmt(ast.For, Statements.s_for),
        _stmt(ast.While, Statements.s_while),
        _stmt(ast.Pass, Statements.s_pass),
        _stmt(ast.Break, Statements.s_break),
        _stmt(ast.Continue, Statements.s_continue),
        _stmt(ast.Assert, Statements.s_assert),
        _stmt(ast.Try, Statements.s_try),
        _stmt(ast.Delete, Statements.s_delete),
    ]
)

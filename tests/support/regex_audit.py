"""Why a regular expression can take more than linear time on Python's backtracking engine, read
from its syntax tree (``re._parser``), and inputs that would show it.

:func:`backtracking_risks` lists what makes a pattern super-linear on some input:

- **nested**: a repeated group (``*``, ``+``, ``{m,n}`` with n > 1) holding another such repeat,
  as in ``(a+)+`` or ``(\\s*,)*``: the ways to split a run between them multiply (unless every
  pass starts or ends with a character the rest of the pass cannot take, ``(?:_[a-z0-9]+)*``);
- **adjacent**: two repeats whose characters overlap, with nothing but optional items
  between them, as in ``[ \\t]*\\w*[ \\t]*\\n``: a run is split between them in every way
  before the match fails (quadratic, cubic with three);
- **leading**: a repeat that can start a match, followed by something required, in a pattern
  that is not anchored, as in ``\\s+and``: a search tries it from every position of a run
  (quadratic), unless the start is guarded (a lookbehind or ``\\b`` that only one position of
  the run passes, or an atom before it that the run cannot match).

Possessive repeats (``*+``) and atomic groups (``(?>...)``) never give back what they took,
so they count as single steps for the first two rules (not for the third: a search restarts
them too). The rules are conservative: a pattern they pass is linear in
the length of its input for ``search``, ``finditer``, ``sub``, ``split`` and ``match``.

:func:`pump_inputs` builds long strings from the characters each repeat takes (with the
pattern's literal prefix in front and a character no repeat takes at the end), the inputs on
which a pattern flagged above would show its cost.
"""

from __future__ import annotations

import re
from collections.abc import Iterator
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # typeshed describes the regex parser under its old names only (deprecated at run time)
    import sre_constants as C
    import sre_parse as P
else:
    import re._constants as C
    import re._parser as P

_UNIVERSE = [chr(c) for c in range(256)] + list("\u00e9\u0416\u0663\u00a0\u2028\u3000\u1680\ufeff\u200b")
_CATEGORY_PATTERN = {
    C.CATEGORY_DIGIT: r"\d", C.CATEGORY_NOT_DIGIT: r"\D", C.CATEGORY_SPACE: r"\s", C.CATEGORY_NOT_SPACE: r"\S",
    C.CATEGORY_WORD: r"\w", C.CATEGORY_NOT_WORD: r"\W",
}  # fmt: skip
_REPEATS = (C.MAX_REPEAT, C.MIN_REPEAT)
_WORD = frozenset(c for c in _UNIVERSE if re.fullmatch(r"\w", c))
_MAX_PATHS = 20_000
_MORE_PASSES: tuple[Any, Any] = (C.ASSERT, (1, []))
"""Stands for the optional further passes of a repeat after its first (matches empty)."""


@dataclass(frozen=True)
class Risk:
    rule: str  # "nested", "adjacent" or "leading"
    detail: str


def _chars(node: tuple[Any, Any], flags: int) -> frozenset[str]:
    """The characters (of a sample universe) one atom matches; every character for others."""
    op, av = node
    if op is C.LITERAL:
        chars = {chr(av)}
    elif op is C.NOT_LITERAL:
        chars = set(_UNIVERSE) - {chr(av)}
    elif op is C.ANY:
        chars = set(_UNIVERSE) if flags & re.DOTALL else set(_UNIVERSE) - {"\n"}
    elif op is C.IN:
        chars = set()
        negate = False
        for item_op, item_av in av:
            if item_op is C.NEGATE:
                negate = True
            elif item_op is C.LITERAL:
                chars.add(chr(item_av))
            elif item_op is C.RANGE:
                chars |= {c for c in _UNIVERSE if item_av[0] <= ord(c) <= item_av[1]}
            elif item_op is C.CATEGORY:
                chars |= {c for c in _UNIVERSE if re.fullmatch(_CATEGORY_PATTERN[item_av], c)}
            else:  # pragma: no cover - charsets the parser does not produce for str patterns
                chars |= set(_UNIVERSE)
        if negate:
            chars = set(_UNIVERSE) - chars
    else:
        return frozenset(_UNIVERSE)
    if flags & re.IGNORECASE:
        chars |= {c.lower() for c in chars} | {c.upper() for c in chars if len(c.upper()) == 1}
    return frozenset(chars)


def _consumes(items: list[tuple[Any, Any]], flags: int) -> frozenset[str]:
    """Every character the items can consume."""
    out: set[str] = set()
    for op, av in items:
        if op in _REPEATS or op is C.POSSESSIVE_REPEAT:
            out |= _consumes(list(av[2]), flags)
        elif op is C.SUBPATTERN:
            out |= _consumes(list(av[3]), flags)
        elif op is C.ATOMIC_GROUP:
            out |= _consumes(list(av), flags)
        elif op is C.BRANCH:
            for alt in av[1]:
                out |= _consumes(list(alt), flags)
        elif op in (C.AT, C.ASSERT, C.ASSERT_NOT):
            continue
        elif op is C.GROUPREF or op is C.GROUPREF_EXISTS:
            out |= set(_UNIVERSE)
        else:
            out |= _chars((op, av), flags)
    return frozenset(out)


def _first(items: list[tuple[Any, Any]], flags: int) -> frozenset[str]:
    """The characters a match of the items can start with."""
    out: set[str] = set()
    for op, av in items:
        if op in _REPEATS or op is C.POSSESSIVE_REPEAT:
            out |= _first(list(av[2]), flags)
        elif op is C.SUBPATTERN:
            out |= _first(list(av[3]), flags)
        elif op is C.ATOMIC_GROUP:
            out |= _first(list(av), flags)
        elif op is C.BRANCH:
            for alt in av[1]:
                out |= _first(list(alt), flags)
        elif op in (C.AT, C.ASSERT, C.ASSERT_NOT):
            continue
        else:
            out |= _consumes([(op, av)], flags)
        if not _nullable((op, av)):
            break
    return frozenset(out)


def _nullable(item: tuple[Any, Any]) -> bool:
    op, av = item
    if op in _REPEATS or op is C.POSSESSIVE_REPEAT:
        return av[0] == 0 or all(_nullable(i) for i in av[2])
    if op is C.SUBPATTERN:
        return all(_nullable(i) for i in av[3])
    if op is C.ATOMIC_GROUP:
        return all(_nullable(i) for i in av)
    if op is C.BRANCH:
        return any(all(_nullable(i) for i in alt) for alt in av[1])
    return op in (C.AT, C.ASSERT, C.ASSERT_NOT)


def _backtracking_repeat(item: tuple[Any, Any]) -> bool:
    op, av = item
    return op in _REPEATS and av[1] > 1


def _any_repeat(item: tuple[Any, Any]) -> bool:
    """A repeat of more than one step, possessive or not (a search restarts either)."""
    op, av = item
    return (op in _REPEATS or op is C.POSSESSIVE_REPEAT) and av[1] > 1


def _paths(items: list[tuple[Any, Any]]) -> Iterator[list[tuple[Any, Any]]]:
    """The sequences of items a match may walk: groups inlined, each branch alternative taken
    in turn (repeats, possessive repeats and atomic groups stay single items)."""
    if not items:
        yield []
        return
    head, rest = items[0], items[1:]
    op, av = head
    if op is C.SUBPATTERN:
        yield from _paths(list(av[3]) + rest)
    elif op is C.BRANCH:
        for alt in av[1]:
            yield from _paths(list(alt) + rest)
    else:
        for tail in _paths(rest):
            yield [head, *tail]


def _walk(items: list[tuple[Any, Any]]) -> Iterator[list[tuple[Any, Any]]]:
    """Every item list in the tree (the pattern itself, group contents, branches, repeat bodies)."""
    yield items
    for op, av in items:
        if op in _REPEATS or op is C.POSSESSIVE_REPEAT:
            yield from _walk(list(av[2]))
        elif op is C.SUBPATTERN:
            yield from _walk(list(av[3]))
        elif op is C.ATOMIC_GROUP:
            yield from _walk(list(av))
        elif op in (C.ASSERT, C.ASSERT_NOT):
            yield from _walk(list(av[1]))
        elif op is C.BRANCH:
            for alt in av[1]:
                yield from _walk(list(alt))


def _contains_backtracking_repeat(items: list[tuple[Any, Any]]) -> bool:
    for sub in _walk(items):
        for op, av in sub:
            if _backtracking_repeat((op, av)):
                return True
    return False


def _delimited(body: list[tuple[Any, Any]], flags: int) -> bool:
    """Whether every pass of a repeated ``body`` starts (or ends) with one required character that
    the rest of the body cannot take, as ``(?:_[a-z0-9]+)*``: the passes then split a text in one
    way only, and the repeat inside a pass is checked on its own (the adjacency rule)."""
    items = list(_paths(body))
    if len(items) != 1 or len(items[0]) < 2:
        return False
    path = items[0]
    for edge, rest in ((path[0], path[1:]), (path[-1], path[:-1])):
        if edge[0] in (C.LITERAL, C.NOT_LITERAL, C.IN, C.ANY) and not _chars(edge, flags) & _consumes(rest, flags):
            return True
    return False


def _guarded(prefix: list[tuple[Any, Any]], run: frozenset[str], flags: int) -> bool:
    """Whether the items before a leading repeat let at most one position of a run of ``run``
    characters start a match."""
    for op, av in prefix:
        if op is C.AT:
            if av is C.AT_BEGINNING_STRING or (av is C.AT_BEGINNING and not flags & re.MULTILINE):
                return True
            if av in (C.AT_BOUNDARY, C.AT_UNI_BOUNDARY) and run <= _WORD:
                return True
        elif op in (C.ASSERT, C.ASSERT_NOT) and av[0] < 0:  # a lookbehind of one character
            behind = _consumes(list(av[1]), flags)
            if op is C.ASSERT and not behind & run:
                return True
            if op is C.ASSERT_NOT and run <= behind:
                return True
        elif not _nullable((op, av)) and not _consumes([(op, av)], flags) & run:
            return True
    return False


def _leading(path: list[tuple[Any, Any]], before: list[tuple[Any, Any]], flags: int, risks: list[Risk]) -> None:
    """The leading rule along one path: the repeats a search can start a match with (after
    optional items and single characters), including those inside the first pass of a leading
    repeated or optional group."""
    for i, item in enumerate(path):
        op, av = item
        prefix = before + path[:i]
        rest = path[i + 1 :]
        if _any_repeat(item):
            run = _consumes([item], flags)
            if not all(_nullable(r) for r in rest) and not _guarded(prefix, run, flags):
                risks.append(Risk("leading", f"a search may start this repeat anywhere in a run: {item}"))
        if op in _REPEATS or op is C.POSSESSIVE_REPEAT:  # the first pass: its body, then the rest
            for body in _paths(list(av[2])):
                _leading([*body, _MORE_PASSES, *rest], prefix, flags, risks)
            return
        if op is C.ATOMIC_GROUP:
            for body in _paths(list(av)):
                _leading(body + rest, prefix, flags, risks)
            return
        if not (_nullable(item) or op in (C.LITERAL, C.NOT_LITERAL, C.ANY, C.IN)):
            return


def backtracking_risks(pattern: str | bytes, flags: int = 0) -> list[Risk]:
    """What could make ``pattern`` super-linear (see the module docstring); [] when nothing."""
    text = pattern.decode("latin-1") if isinstance(pattern, bytes) else pattern
    parsed = P.parse(text, flags)
    flags |= parsed.state.flags
    items = list(parsed.data)
    risks: list[Risk] = []
    for sub in _walk(items):
        for op, av in sub:
            body = list(av[2]) if op in _REPEATS else []
            if _backtracking_repeat((op, av)) and _contains_backtracking_repeat(body) and not _delimited(body, flags):
                risks.append(Risk("nested", f"a repeat holds a repeat: {(op, av)}"))
    for count, path in enumerate(p for sub in _walk(items) for p in _paths(sub)):
        if count > _MAX_PATHS:
            risks.append(Risk("adjacent", "too many alternatives to check"))
            break
        for i, item in enumerate(path):
            if not _backtracking_repeat(item):
                continue
            mine = _consumes([item], flags)
            for later in path[i + 1 :]:
                if _backtracking_repeat(later) and mine & _first([later], flags):
                    risks.append(Risk("adjacent", f"overlapping repeats: {item} then {later}"))
                    break
                if not _nullable(later):
                    break
    for count, path in enumerate(_paths(items)):
        if count > _MAX_PATHS:
            break
        _leading(path, [], flags, risks)
    return list(dict.fromkeys(risks))


def _repeat_sets(items: list[tuple[Any, Any]], flags: int) -> list[frozenset[str]]:
    return [
        _consumes(list(av[2]), flags)
        for sub in _walk(items)
        for op, av in sub
        if op in _REPEATS or op is C.POSSESSIVE_REPEAT
    ]


def _literal_prefix(items: list[tuple[Any, Any]]) -> str:
    out = []
    for op, av in items:
        if op is C.LITERAL:
            out.append(chr(av))
        elif op is C.SUBPATTERN:
            inner = list(av[3])
            out.append(_literal_prefix(inner))
            if len(out[-1]) < len(inner):
                break
        elif op is not C.AT:
            break
    return "".join(out)


def pump_inputs(pattern: str | bytes, flags: int = 0, length: int = 100_000) -> list[str | bytes]:
    """Long inputs built from the characters the pattern's repeats take (see the module doc)."""
    text = pattern.decode("latin-1") if isinstance(pattern, bytes) else pattern
    parsed = P.parse(text, flags)
    flags |= parsed.state.flags
    items = list(parsed.data)
    prefix = _literal_prefix(items)
    sets = [s for s in _repeat_sets(items, flags) if s]
    taken = frozenset().union(*sets) if sets else frozenset()
    stop = next((c for c in "\x00!\x7f#~" + "".join(_UNIVERSE) if c not in taken), "\x00")
    reps = sorted({min(s) for s in sets} | {c for s in sets for c in " a0_," if c in s})[:5]
    out: list[str] = []
    for c in reps:
        out += [c * length + stop, prefix + c * length + stop, prefix + (c + stop) * (length // 2)]
        out += [prefix + (c + d) * (length // 2) + stop for d in reps if d != c]
    out = list(dict.fromkeys(out))
    if isinstance(pattern, bytes):
        return [s.encode("latin-1", "replace") for s in out if all(ord(ch) < 256 for ch in s)]
    return list(out)

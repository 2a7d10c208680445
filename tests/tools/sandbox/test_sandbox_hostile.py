"""Hostile event programs: every one ends in a typed error, escapes nothing, changes nothing."""

from __future__ import annotations

import copy
from collections.abc import Callable

import pytest

from storyteller.tools.errors import EventProgramError, ToolArgumentError
from storyteller.tools.sandbox import (
    Budget,
    BudgetExceededError,
    ForbiddenConstructError,
    ProgramRuntimeError,
    ProgramSyntaxError,
    execute,
    run_program,
)
from tests.support.hostile_programs import HOSTILE, World, body


@pytest.mark.parametrize(
    ("source", "expected"), [(s, e) for _, s, e in HOSTILE], ids=[n for n, _, _ in HOSTILE]
)
def test_hostile_program_fails_typed_and_changes_nothing(
    source: str, expected: type[EventProgramError]
) -> None:
    world = World()
    namespace = world.namespace()
    before = dict(namespace)
    sentinel = copy.deepcopy(namespace["SENTINEL"])
    with pytest.raises(EventProgramError) as info:
        execute(source, namespace)
    assert type(info.value) is expected, info.value.feedback
    assert info.value.feedback and str(info.value) == info.value.feedback
    assert namespace.keys() == before.keys()
    assert all(namespace[k] is before[k] for k in before)
    assert namespace["SENTINEL"] == sentinel
    assert world.state == {"occupied": ["chair_1"]}
    assert world.plans == {}


def test_there_are_at_least_forty_hostile_programs() -> None:
    assert len(HOSTILE) >= 40
    assert len({name for name, _, _ in HOSTILE}) == len(HOSTILE)




# RANGE_MEMBERSHIP runs in tests/tools/sandbox/test_sandbox_real_api.py, in a subprocess with a hang
# detector (a regression would hang in C); here the same rule is checked on small ranges.
ITEMS: list[tuple[str, object]] = [
    ("0.5", 0.5), ("3.0", 3.0), ("-2.0", -2.0), ("4.0", 4.0), ("'a'", "a"), ("None", None),
    ("[1]", [1]), ("(1, 2)", (1, 2)), ("True", True), ("float('nan')", float("nan")),
]  # fmt: skip
RANGES = [(-10, 10), (1, 30, 3), (20, -20, -2), (0,)]


@pytest.mark.parametrize(("text", "item"), ITEMS, ids=[t for t, _ in ITEMS])
@pytest.mark.parametrize("bounds", RANGES, ids=map(str, RANGES))
def test_membership_in_ranges_is_arithmetic_and_agrees_with_python(
    text: str, item: object, bounds: tuple[int, ...]
) -> None:
    expected = item in range(*bounds)  # small ranges: Python's own scan is quick
    args = ", ".join(map(str, bounds))
    run = run_program(body(f"return {text} in range({args})"), {})
    assert run.result is expected
    assert run.steps < 50


@pytest.mark.parametrize(
    "expression",
    [
        "set([i % 7 for i in range(20000)])",
        "set([float(i % 7) for i in range(20000)])",
        "set(range(20000)) == set(range(20000))",
        "dict([(i, i) for i in range(5000)])",
        "{*range(5000)} | {*range(2500, 7500)}",
        "set([(i % 3, None) for i in range(3000)])",
    ],
)
def test_duplicate_and_distinct_keys_are_not_mistaken_for_hash_collisions(
    expression: str,
) -> None:
    execute(body(f"return {expression}"), {})


def test_tool_results_and_constants_are_not_aliased() -> None:
    world = World()
    namespace = world.namespace()
    source = body(
        "s = get_state()\ns['occupied'].clear()\ns['hacked'] = True\n"
        "SENTINEL['untouched'].append(4)\nSENTINEL.clear()\nreturn s"
    )
    assert execute(source, namespace) == {"occupied": [], "hacked": True}
    assert world.state == {"occupied": ["chair_1"]}
    assert namespace["SENTINEL"] == {"untouched": [1, 2, 3]}


def test_system_exit_inside_a_tool_does_not_escape() -> None:
    def bad_tool() -> None:
        raise SystemExit(3)

    with pytest.raises(ProgramRuntimeError, match="line 2: bad_tool\\(\\) failed: SystemExit"):
        execute(body("bad_tool()"), {"bad_tool": bad_tool})


def test_recursion_error_inside_a_tool_is_a_budget_error() -> None:
    def runaway(n: int) -> int:
        return runaway(n + 1)

    with pytest.raises(BudgetExceededError, match="line 2"):
        execute(body("return runaway(0)"), {"runaway": runaway})


def test_small_budgets_are_enforced() -> None:
    tight = Budget(steps=500, loop_iterations=10**6)
    with pytest.raises(BudgetExceededError, match="steps"):
        execute(body("n = 0\nwhile True:\n    n += 1"), {}, budget=tight)
    with pytest.raises(BudgetExceededError, match="characters"):
        execute(body("return 'x' * 11"), {}, budget=Budget(str_len=10))


# ---------------------------------------------------------------- what a program really costs

NESTED_REFERENCES = "s = 'x' * 20000\na = [s] * 20000\nb = [a] * 20000\n"
"""A list of 20,000 references to a list of 20,000 references to a 20,000-character string:
a few hundred kilobytes, whose full ``repr`` would be 8·10^12 characters."""


@pytest.mark.parametrize(
    ("use", "expected"),
    [
        ("print(b)", BudgetExceededError),
        ("return str(b)", BudgetExceededError),
        ("return f'{b!r}'", BudgetExceededError),
        ("return f'{b!a}'", BudgetExceededError),
        ("return b.index(5)", ProgramRuntimeError),
        ("return a.index(b)", BudgetExceededError),
        ("return b.index([s])", ProgramRuntimeError),
        ("d = {s: 1}\nreturn d.pop(s[1:] + 'y')", ProgramRuntimeError),
        ("return {1: 2}[b[0][0][1:] + 'y']", ProgramRuntimeError),
    ],
)
def test_huge_values_are_never_rendered_in_full(use: str, expected: type[EventProgramError]) -> None:
    source = body(NESTED_REFERENCES + use)
    with pytest.raises(expected) as info:
        run_program(source, World().namespace())
    assert len(info.value.feedback) <= 600  # tools clip too, but only the renderer is cheap


def test_tool_argument_errors_show_a_bounded_value() -> None:
    """``got {value!r}`` in the spatial API goes through the bounded renderer."""
    from storyteller.sim.scene.bundled import load_bundled_scene
    from storyteller.tools.character_states import WorldView
    from storyteller.tools.spatial_api import SpatialAPI

    big = ["x" * 20000] * 20000
    api = SpatialAPI(load_bundled_scene("home"), None, WorldView(), None)
    ns = api.namespace()
    calls: list[Callable[[], object]] = [
        lambda: ns["get_area_to_sit_on"](big),
        lambda: ns["get_character"](big),
        lambda: ns["get_character"]("Mia").set_position([big]),
    ]
    for call in calls:
        with pytest.raises(ToolArgumentError) as info:
            call()
        assert len(info.value.feedback) < 300


def test_big_integers_are_charged_in_bytes() -> None:
    """99 lists of 20,000 distinct 2000-bit integers (about 0.6 GB): within the item counts, not the bytes."""
    source = body(
        "out = []\nfor k in range(99):\n"
        "    out.append(list(range(2**2000 + k * 20000, 2**2000 + (k + 1) * 20000)))\n"
        "return len(out)"
    )
    with pytest.raises(BudgetExceededError, match="MiB") as info:
        run_program(source, {})
    assert info.value.steps is not None and info.value.steps < 1000  # stopped early


def test_big_integers_from_arithmetic_are_charged() -> None:
    source = body(
        "x = 2**2000\nout = [x + i for i in range(20000)]\nreturn [out, [x * 3 + i for i in range(20000)]]"
    )
    tight = Budget(memory_bytes=4 * 2**20)
    with pytest.raises(BudgetExceededError, match="MiB"):
        run_program(source, {}, budget=tight)


def test_enumerate_start_is_bounded() -> None:
    with pytest.raises(BudgetExceededError, match="bits"):
        execute(body("return enumerate([1, 2], 2**4096 - 1)"), {})
    assert execute(body("return enumerate(['a'], 5)"), {}) == [(5, "a")]


def test_a_long_program_with_thousands_of_names_is_refused_by_the_checker() -> None:
    """20,000 characters and thousands of unknown names: no quadratic suggestion search."""
    from storyteller.tools.sandbox import check_program

    names = [f"v{i}x" for i in range(3000)]
    source = body("\n".join(f"{n} = w{n}" for n in names))[:20000]
    with pytest.raises(BudgetExceededError, match="different names"):
        check_program(source, {})
    unknown = body("\n".join(f"q = y{i} + z{i}" for i in range(900)))[:20000]
    with pytest.raises(EventProgramError, match="'y0' is not defined"):
        check_program(unknown, {f"y{i}0": 1 for i in range(5000)})


def test_the_checker_has_its_own_clock_and_node_limit() -> None:
    from storyteller.tools.sandbox import check_program

    ticks = iter(range(10**6))
    source = body("x = [" + ", ".join(["1"] * 3000) + "]\nreturn x")
    with pytest.raises(BudgetExceededError, match="checking the program took longer"):
        check_program(source, {"a_tool": 1}, budget=Budget(check_time=5), clock=lambda: next(ticks))
    with pytest.raises(BudgetExceededError, match="syntax nodes"):
        check_program(source, {}, budget=Budget(check_nodes=1000))


def test_failed_checks_are_cached() -> None:
    from storyteller.tools.sandbox import checker

    source = body("return undefined_name_9")
    for _ in range(2):
        with pytest.raises(EventProgramError, match="undefined_name_9") as info:
            checker.check_program(source, {})
        assert info.value.line == 2
    key: tuple[str, frozenset[str], Budget] = (source, frozenset(), Budget())
    assert isinstance(checker._CACHE.get(key), EventProgramError)


def test_the_check_cache_is_bounded_in_bytes() -> None:
    from storyteller.tools.sandbox.checker import NODE_BYTES, _CheckCache

    cache = _CheckCache(max_bytes=10 * NODE_BYTES)
    for i in range(20):
        cache.put((f"p{i}", frozenset(), Budget()), ProgramSyntaxError("x"), 3 * NODE_BYTES)
    assert cache.bytes <= 10 * NODE_BYTES
    assert len(cache.entries) == 3
    assert cache.get(("p19", frozenset(), Budget())) is not None


def test_small_fixes_from_the_second_corpus() -> None:
    assert execute(body("x = [1, 2, 3]\nx[0:1] += [9]\nreturn x"), {}) == [1, 9, 2, 3]
    with pytest.raises(ForbiddenConstructError, match="async"):
        execute(body("return [x async for x in y]"), {"y": []})
    text = execute(
        body("return str([get_character, get_character('Mia').set_position])"), World().namespace()
    )
    assert "0x" not in str(text)
    assert execute(body("a = []\na.append(a)\nreturn f'{a}'"), {}) == "[[...]]"


def test_suggestions_look_at_a_bounded_number_of_keys() -> None:
    source = body("d = {f'key{i}': i for i in range(20000)}\nreturn d['key19999x']")
    with pytest.raises(ProgramRuntimeError, match="not in the dict") as info:
        run_program(source, {})
    assert info.value.steps is not None and info.value.steps < Budget().steps


# ---------------------------------------------------------------- program text is data on the CLI

MARKUP_NAMES = {
    "[/]": "get_area_adjacent_to('fridge_1')",
    "[red]Ivy[bold": "get_area_to_sit_on('chair_2')",
}


@pytest.mark.parametrize("in_process", [True, False], ids=["in_process", "worker"])
def test_markup_and_escapes_in_names_are_printed_as_text(
    tmp_path: object, in_process: bool
) -> None:
    from pathlib import Path

    from typer.testing import CliRunner

    from storyteller.orchestrator.cli.app import app

    assert isinstance(tmp_path, Path)
    lines = [
        f"    get_character({name!r}).set_position({area})" for name, area in MARKUP_NAMES.items()
    ]
    program = tmp_path / "p.py"
    program.write_text("def parse_event():\n" + "\n".join(lines) + "\n", encoding="utf-8")
    args = ["event-program", "home", "--program", str(program)]
    result = CliRunner().invoke(app, args + (["--in-process"] if in_process else []))
    assert result.exit_code == 0, result.output
    assert result.exception is None
    for name in MARKUP_NAMES:
        assert name in result.output, result.output
    # terminal escapes and bidi overrides in an error message reach the terminal as text
    program.write_text(
        "def parse_event():\n    assert False, '\\x1b[2J\\x1b[31mred \\u202eevil [/]'\n",
        encoding="utf-8",
    )
    result = CliRunner().invoke(app, args + (["--in-process"] if in_process else []))
    assert result.exit_code == 1
    assert result.exception is None or isinstance(result.exception, SystemExit)
    assert "\x1b" not in result.output and "\u202e" not in result.output
    assert "\\x1b[31mred \\u202eevil [/]" in result.output, result.output


def test_safe_text_strips_every_control_character() -> None:
    from storyteller.orchestrator.safe_text import markup, plain

    hostile = "".join(chr(c) for c in range(0x00, 0xA0)) + "\u202e\u2066"
    cleaned = plain(hostile)
    assert not any(ord(c) < 0x20 or 0x7F <= ord(c) < 0xA0 for c in cleaned)
    assert "\u202e" not in cleaned
    assert plain("a\nb", keep_newlines=True) == "a\nb"
    assert plain("a\nb") == "a\\x0ab"
    assert markup("[red]x[/]") == "\\[red]x\\[/]"

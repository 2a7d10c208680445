"""The event-program sandbox runs ordinary programs and explains failures with line numbers."""

from __future__ import annotations

import math
from typing import ClassVar

import pytest

from storyteller.tools.errors import EventProgramError, ToolArgumentError, UnknownObjectError, did_you_mean
from storyteller.tools.sandbox import (
    Budget,
    BudgetExceededError,
    ForbiddenConstructError,
    MissingEntryError,
    ProgramRuntimeError,
    ProgramSyntaxError,
    UnknownNameError,
    execute,
    run_program,
)

OBJECTS = ("chair_1", "chair_2", "chair_3", "dining_table_1", "sofa_1", "tv_stand_1")


class FakeCharacter:
    """Stands in for the spatial API's character handle: records its plan."""

    sandbox_attributes: ClassVar[frozenset[str]] = frozenset(
        {"name", "set_position", "set_orientation", "set_target_action"}
    )

    def __init__(self, name: str, plans: dict[str, dict[str, object]]) -> None:
        self.name = name
        self._plans = plans

    def set_position(self, area: object) -> None:
        if (
            isinstance(area, list | tuple)  # an xy pair, not an area name
            and len(area) == 2
            and not isinstance(area[0], str)
            and not all(isinstance(v, int | float) and math.isfinite(v) for v in area)
        ):
            raise ToolArgumentError(f"position {area!r} must be two finite numbers")
        self._plans.setdefault(self.name, {})["position"] = area

    def set_orientation(self, target: str) -> None:
        self._plans.setdefault(self.name, {})["orientation"] = target

    def set_target_action(self, label: str) -> None:
        self._plans.setdefault(self.name, {})["action"] = label


class FakeWorld:
    """A tiny spatial API: names, occupancy, distances, areas as tuples."""

    def __init__(self) -> None:
        self.plans: dict[str, dict[str, object]] = {}
        self.occupied = {"chair_1"}
        self.calls = 0

    def _object(self, name: object) -> str:
        if name not in OBJECTS:
            raise UnknownObjectError(f"unknown object {name!r};{did_you_mean(str(name), OBJECTS)}")
        return str(name)

    def get_character(self, name: str) -> FakeCharacter:
        return FakeCharacter(name, self.plans)

    def is_object_occupied(self, name: str) -> bool:
        return self._object(name) in self.occupied

    def get_objects_close_to(self, name: str) -> list[str]:
        self._object(name)
        return [o for o in OBJECTS if o.startswith("chair")]

    def get_distance_between(self, a: str, b: str) -> float:
        return float(abs(OBJECTS.index(self._object(a)) - OBJECTS.index(self._object(b))))

    def get_area_to_sit_on(self, name: str) -> tuple[str, str]:
        return ("sit_on", self._object(name))

    def get_area_close_to(self, name: str) -> tuple[str, str]:
        return ("close_to", self._object(name))

    def namespace(self) -> dict[str, object]:
        return {
            "get_character": self.get_character,
            "is_object_occupied": self.is_object_occupied,
            "get_objects_close_to": self.get_objects_close_to,
            "get_distance_between": self.get_distance_between,
            "get_area_to_sit_on": self.get_area_to_sit_on,
            "get_area_close_to": self.get_area_close_to,
            "SEATS": ["chair_1", "chair_2", "chair_3"],
        }


REALISTIC = """
TABLE = "dining_table_1"


def free_seats(anchor, exclude=()):
    seats = [o for o in get_objects_close_to(anchor) if o.startswith("chair")]
    return [s for s in seats if not is_object_occupied(s) and s not in exclude]


def parse_event():
    diners = ["Mia", "Leo"]
    seats = sorted(free_seats(TABLE), key=lambda s: get_distance_between(s, TABLE))
    plans = {}
    for i, name in enumerate(diners):
        c = get_character(name)
        if i < len(seats):
            c.set_position(get_area_to_sit_on(seats[i]))
            c.set_target_action("eat")
        else:
            c.set_position(get_area_close_to(TABLE))
            c.set_target_action("chat")
        c.set_orientation(TABLE)
        plans[c.name] = seats[i] if i < len(seats) else None
    print(f"seated {len(plans)} diners: {plans}")
    return plans
"""


def test_realistic_program_drives_tools_and_handles() -> None:
    world = FakeWorld()
    run = run_program(REALISTIC, world.namespace())
    assert run.result == {"Mia": "chair_3", "Leo": "chair_2"}
    assert world.plans == {
        "Mia": {
            "position": ("sit_on", "chair_3"),
            "action": "eat",
            "orientation": "dining_table_1",
        },
        "Leo": {
            "position": ("sit_on", "chair_2"),
            "action": "eat",
            "orientation": "dining_table_1",
        },
    }
    assert run.output == ("seated 2 diners: {'Mia': 'chair_3', 'Leo': 'chair_2'}",)
    assert 0 < run.steps < 1000


@pytest.mark.parametrize(
    ("body", "expected"),
    [
        ("return [i * i for i in range(5) if i % 2]", [1, 9]),
        ("return {k: v for k, v in zip('ab', [1, 2])}", {"a": 1, "b": 2}),
        ("return {x % 3 for x in range(10)}", {0, 1, 2}),
        ("return sum(x for x in range(4))", 6),
        ("return any(s == 'chair_2' for s in SEATS), all([1, 0])", (True, False)),
        ("a, *rest = [1, 2, 3]\n    return a, rest", (1, [2, 3])),
        ("x = [1, 2]\n    x += (3,)\n    x[0] -= 5\n    return x", [-4, 2, 3]),
        (
            "d = {'n': 1}\n    d['n'] += 1\n    d.setdefault('m', []).append(2)\n    return d",
            {"n": 2, "m": [2]},
        ),
        ("return f'{1.23456:.2f}|{\"ab\":>4}|{7:03d}|{[1]!r}'", "1.23|  ab|007|[1]"),
        (
            "n = 0\n    while True:\n        n += 1\n        if n > 3:\n            break\n    return n",
            4,
        ),
        (
            "for i in range(3):\n        if i == 5:\n            break\n    else:\n        return 'no break'",
            "no break",
        ),
        (
            "out = []\n    for i in range(5):\n        if i % 2:\n            continue\n        out.append(i)\n    return out",
            [0, 2, 4],
        ),
        ("return min(SEATS, key=lambda s: -len(s) if s != 'chair_2' else 0)", "chair_1"),
        ("return max([3, 1, 2]), min(4, 2, 8), abs(-2), round(2.567, 1)", (3, 2, 2, 2.6)),
        ("return sorted({'b': 1, 'a': 2}.items(), reverse=True)", [("b", 1), ("a", 2)]),
        ("return ' '.join(w.upper() for w in 'a b'.split()).replace('A', 'x')", "x B"),
        ("return 'Chair_1'.lower().startswith('chair'), 'a,b'.split(',')", (True, ["a", "b"])),
        (
            "return list(reversed([1, 2])), tuple(enumerate('ab', 1))",
            ([2, 1], ((1, "a"), (2, "b"))),
        ),
        ("return [1, 2, 3, 4][::-2], 'abcdef'[1:3], (1, 2)[-1]", ([4, 2], "bc", 2)),
        ("return int('7') + int(2.9), float('1.5'), str(12), bool([])", (9, 1.5, "12", False)),
        ("return 7 // 2, 7 % 3, 2 ** 10, 1 << 4, -3 / 2", (3, 1, 1024, 16, -1.5)),
        ("return 1 < 2 < 3, 1 < 3 < 2, 'a' in 'cat', 3 not in [1]", (True, False, True, True)),
        ("return (y := 5) + y", 10),
        (
            "s = set()\n    s.add(1)\n    s.update([2, 2])\n    return s | {3}, s.issubset({1, 2, 9})",
            ({1, 2, 3}, True),
        ),
        ("x: int = 3\n    return x if x > 2 else -x", 3),
        ("del_me = [1, 2, 3]\n    del del_me[0]\n    return del_me", [2, 3]),
        (
            "return dict(a=1), dict([('b', 2)]), list('ab'), len({'a': 1})",
            ({"a": 1}, {"b": 2}, ["a", "b"], 1),
        ),
    ],
)
def test_language_features(body: str, expected: object) -> None:
    source = f"def parse_event():\n    {body}\n"
    assert execute(source, FakeWorld().namespace()) == expected


def test_helpers_closures_recursion_and_defaults() -> None:
    source = """
def make_counter(start=10):
    def add(n, twice=False):
        return start + (2 * n if twice else n)
    return add


def fact(n):
    return 1 if n <= 1 else n * fact(n - 1)


def parse_event():
    add = make_counter()
    return add(1), add(n=2, twice=True), fact(10), (lambda a, b=2: a * b)(4)
"""
    assert execute(source, {}) == (11, 14, 3628800, 8)


def test_try_except_catches_tool_errors_only() -> None:
    source = """
def parse_event():
    found = []
    for name in ["chair_2", "chiar_9", "sofa_1"]:
        try:
            occupied = is_object_occupied(name)
        except UnknownObjectError as err:
            found.append(err)
        else:
            found.append(occupied)
        finally:
            found.append("checked")
    return found
"""
    result = execute(source, FakeWorld().namespace())
    assert isinstance(result, list)
    assert result[0:2] == [False, "checked"]
    assert isinstance(result[2], str) and "unknown object 'chiar_9'" in result[2]
    assert result[3:] == ["checked", False, "checked"]


def test_except_does_not_catch_runtime_or_budget_errors() -> None:
    runtime = "def parse_event():\n    try:\n        return 1 / 0\n    except Exception:\n        return 'caught'\n"
    with pytest.raises(ProgramRuntimeError, match="line 3: division by zero"):
        execute(runtime, {})
    budget = "def parse_event():\n    try:\n        while True:\n            pass\n    except:\n        return 'caught'\n"
    with pytest.raises(BudgetExceededError):
        execute(budget, {}, budget=Budget(loop_iterations=50))


def test_unknown_name_names_line_and_suggests() -> None:
    source = "def parse_event():\n    c = get_character('Mia')\n    c.set_position(get_area_clos_to('sofa_1'))\n"
    with pytest.raises(UnknownNameError) as info:
        execute(source, FakeWorld().namespace())
    assert info.value.feedback == (
        "line 3: name 'get_area_clos_to' is not defined; did you mean 'get_area_close_to'?"
    )
    assert info.value.line == 3


def test_tool_error_propagates_unchanged_with_line() -> None:
    source = "def parse_event():\n\n    return get_area_to_sit_on('chiar_2')\n"
    with pytest.raises(UnknownObjectError) as info:
        execute(source, FakeWorld().namespace())
    assert info.value.feedback.startswith(
        "line 3: unknown object 'chiar_2'; did you mean 'chair_2'"
    )
    assert str(info.value) == info.value.feedback


def test_tool_type_error_becomes_runtime_error_naming_the_function() -> None:
    source = "def parse_event():\n    return get_distance_between('sofa_1')\n"
    with pytest.raises(ProgramRuntimeError) as info:
        execute(source, FakeWorld().namespace())
    feedback = info.value.feedback
    assert feedback.startswith("line 2: get_distance_between() failed: TypeError")
    assert "(a: 'str', b: 'str')" in feedback or "(a: str, b: str)" in feedback


def test_attribute_suggestion_on_handles() -> None:
    source = "def parse_event():\n    c = get_character('Mia')\n    c.set_pos(get_area_close_to('sofa_1'))\n"
    with pytest.raises(
        ProgramRuntimeError,
        match="line 3: 'FakeCharacter' object has no attribute 'set_pos'; did you mean 'set_position'",
    ):
        execute(source, FakeWorld().namespace())


@pytest.mark.parametrize(
    ("source", "error", "fragment"),
    [
        (
            "def parse_event():\n    return [1][3]",
            ProgramRuntimeError,
            "line 2: list index 3 out of range (length 1)",
        ),
        (
            "def parse_event():\n    return {'seat': 1}['set']",
            ProgramRuntimeError,
            "line 2: key 'set' is not in the dict; did you mean 'seat'?",
        ),
        ("def parse_event():\n    return 'a' + 1", ProgramRuntimeError, "line 2: '+' failed"),
        (
            "def parse_event():\n    x = 1\n    assert x == 2, 'bad x'",
            ProgramRuntimeError,
            "line 3: assertion failed: `x == 2`: bad x",
        ),
        (
            "def parse_event(scene):\n    pass",
            ProgramRuntimeError,
            "parse_event() is called without arguments; remove its parameters (scene)",
        ),
        (
            "def parse_events():\n    pass",
            MissingEntryError,
            "define a function `def parse_event():`; did you mean 'parse_events'?",
        ),
        ("x = 1", MissingEntryError, "it defines no functions"),
        ("def parse_event()\n    pass", ProgramSyntaxError, "line 1: syntax error"),
        (
            "def parse_event():\n    return y\n    y = 1",
            ProgramRuntimeError,
            "line 2: variable 'y' is used before it is assigned",
        ),
        (
            "def parse_event():\n    return getattr(1, 'real')",
            ForbiddenConstructError,
            "line 2: 'getattr' is not available",
        ),
        (
            "def helper(a):\n    return a\ndef parse_event():\n    return helper(1, 2)",
            ProgramRuntimeError,
            "line 4: helper() takes 1 arguments but 2 were given",
        ),
    ],
)
def test_error_messages(source: str, error: type[EventProgramError], fragment: str) -> None:
    with pytest.raises(error) as info:
        execute(source, FakeWorld().namespace())
    assert fragment in info.value.feedback


def test_earliest_problem_is_reported() -> None:
    source = "def parse_event():\n    a = nope_1\n    import os\n    return a.__dict__\n"
    with pytest.raises(UnknownNameError, match="line 2"):
        execute(source, {})


def test_namespace_constants_are_copied_not_mutated() -> None:
    world = FakeWorld()
    namespace = world.namespace()
    source = "def parse_event():\n    SEATS.append('x')\n    SEATS[0] = 'y'\n    return SEATS\n"
    assert execute(source, namespace) == ["y", "chair_2", "chair_3", "x"]
    assert namespace["SEATS"] == ["chair_1", "chair_2", "chair_3"]


def test_top_level_entry_call_is_not_run_twice() -> None:
    world = FakeWorld()
    source = "calls = []\ndef parse_event():\n    calls.append(1)\n    return len(calls)\nparse_event()\n"
    assert execute(source, world.namespace()) == 1


def test_other_entry_and_annotations() -> None:
    source = "def plan(n: int = 2) -> list[int]:\n    return [n] * n\n"
    assert execute(source, {}, entry="plan") == [2, 2]


def test_wall_time_uses_injected_clock() -> None:
    ticks = iter(range(10**6))

    def clock() -> float:
        return next(ticks) * 0.25  # every reading is a quarter second later

    source = (
        "def parse_event():\n    n = 0\n    for i in range(5000):\n        n += i\n    return n\n"
    )
    with pytest.raises(BudgetExceededError, match="ran longer than 1 s"):
        execute(source, {}, clock=clock)
    # a frozen clock never runs out of time
    assert execute(source, {}, clock=lambda: 0.0) == sum(range(5000))


def test_slow_tool_exhausts_wall_time() -> None:
    now = [0.0]

    def slow_tool() -> int:
        now[0] += 0.6
        return 1

    source = "def parse_event():\n    return slow_tool() + slow_tool()\n"
    with pytest.raises(BudgetExceededError, match="line 2"):
        execute(source, {"slow_tool": slow_tool}, clock=lambda: now[0])


def test_default_clock_counts_cpu_time_not_waiting() -> None:
    # A busy machine must not change a verdict (a replay under load gives the recording's):
    # the default clock is the thread's CPU time, so time spent not running is not counted.
    import time

    def waiting_tool() -> int:
        time.sleep(0.6)  # the thread is off the CPU, as when the machine is busy
        return 1

    source = "def parse_event():\n    return waiting_tool() + waiting_tool()\n"
    assert execute(source, {"waiting_tool": waiting_tool}) == 2
    # the same program under a wall clock runs out of time (the old default)
    with pytest.raises(BudgetExceededError, match="ran longer than 1 s"):
        execute(source, {"waiting_tool": waiting_tool}, clock=time.monotonic)


def test_print_is_captured() -> None:
    run = run_program("def parse_event():\n    print('a', 1, sep='-')\n    print('b\\nc')\n", {})
    assert run.output == ("a-1", "b", "c")
    assert run.result is None


def test_parser_warnings_do_not_turn_into_errors() -> None:
    # pytest runs with warnings as errors; an invalid escape must still parse as in production
    assert execute("def parse_event():\n    return '\\d'\n", {}) == "\\d"


class Region:
    """An opaque tool value that declares its operators and one property."""

    sandbox_attributes: ClassVar[frozenset[str]] = frozenset({"cells"})
    sandbox_operators: ClassVar[frozenset[str]] = frozenset({"|", "[]"})

    def __init__(self, cells: set[int]) -> None:
        self._cells = cells

    @property
    def cells(self) -> list[int]:
        return sorted(self._cells)

    def __or__(self, other: Region) -> Region:
        return Region(self._cells | other._cells)

    def __getitem__(self, i: int) -> int:
        return self.cells[i]

    def secret(self) -> str:
        return "hidden"


def test_opaque_tool_values_expose_only_what_they_declare() -> None:
    ns = {"region": lambda *cells: Region(set(cells))}
    assert execute(
        "def parse_event():\n    r = region(1, 2) | region(3)\n    return r.cells, r[0]\n", ns
    ) == ([1, 2, 3], 1)
    with pytest.raises(ForbiddenConstructError, match=r"'Region\.secret' is not available"):
        execute("def parse_event():\n    return region(1).secret()\n", ns)
    with pytest.raises(ProgramRuntimeError, match="unsupported operand types for &"):
        execute("def parse_event():\n    return region(1) & region(2)\n", ns)
    with pytest.raises(ProgramRuntimeError, match="cannot loop over a value of type 'Region'"):
        execute("def parse_event():\n    return [c for c in region(1)]\n", ns)

"""The hostile event-program corpus: programs that must each end in one typed error (``HOSTILE``)
or in a plain value computed without a hang (``RANGE_MEMBERSHIP``), and the stand-in world they
run against (``World``, whose ``Handle`` keeps private state out of reach).

Run in-process by ``tests/tools/sandbox/test_sandbox_hostile.py`` and against the real spatial API, in a
subprocess with a hang detector, by ``tests/tools/sandbox/test_sandbox_real_api.py``.
"""

from __future__ import annotations

from typing import ClassVar

from storyteller.tools.errors import EventProgramError, ToolArgumentError, UnknownObjectError
from storyteller.tools.sandbox import (
    BudgetExceededError,
    ForbiddenConstructError,
    ProgramRuntimeError,
    ProgramSyntaxError,
)


class Handle:
    """A character handle whose private state must stay out of reach."""

    sandbox_attributes: ClassVar[frozenset[str]] = frozenset({"name", "set_position"})

    def __init__(self, name: str, plans: dict[str, object]) -> None:
        self.name = name
        self._plans = plans

    def set_position(self, position: object) -> None:
        if not (
            isinstance(position, list | tuple)
            and len(position) == 2
            and all(isinstance(v, float | int) and abs(v) < 1e6 for v in position)
        ):
            raise ToolArgumentError(f"position must be two finite numbers, got {position!r}")
        self._plans[self.name] = tuple(position)


class World:
    def __init__(self) -> None:
        self.plans: dict[str, object] = {}
        self.state = {"occupied": ["chair_1"]}

    def get_character(self, name: str) -> Handle:
        return Handle(name, self.plans)

    def get_area_to_sit_on(self, name: str) -> tuple[str, str]:
        if name != "chair_1":
            raise UnknownObjectError(f"unknown object {name!r}")
        return ("sit_on", name)

    def get_state(self) -> dict[str, list[str]]:
        return self.state  # deliberately aliases internal state (a careless tool)

    def namespace(self) -> dict[str, object]:
        return {
            "get_character": self.get_character,
            "get_area_to_sit_on": self.get_area_to_sit_on,
            "get_state": self.get_state,
            "SENTINEL": {"untouched": [1, 2, 3]},
            "_secret": object(),
        }


def body(code: str) -> str:
    """Wrap statements (4-space indented by the caller's newlines) into parse_event()."""
    lines = code.split("\n")
    return "def parse_event():\n" + "\n".join("    " + line for line in lines) + "\n"


F, B, R, S = ForbiddenConstructError, BudgetExceededError, ProgramRuntimeError, ProgramSyntaxError

HOSTILE: list[tuple[str, object, type[EventProgramError]]] = [
    # imports and the Python object model
    ("import_os", "import os\ndef parse_event():\n    pass\n", F),
    ("from_import", "from os import system\ndef parse_event():\n    pass\n", F),
    ("dunder_import", body("return __import__('os')"), F),
    ("import_in_function", body("import subprocess"), F),
    ("subclasses_walk", body("return ().__class__.__bases__[0].__subclasses__()"), F),
    ("getattr_built_name", body("return getattr(1, '__cl' + 'ass__')"), F),
    ("str_format_walk", body("return '{0.__class__}'.format(1)"), F),
    ("format_map", body("return '{x}'.format_map({'x': 1})"), F),
    ("fstring_dunder", body("x = 1\nreturn f'{x.__class__}'"), F),
    ("generator_frame", body("return (x for x in []).gi_frame.f_globals"), R),
    (
        "traceback_frame",
        body(
            "try:\n    get_area_to_sit_on('sofa_9')\nexcept Exception as e:\n    return e.__traceback__.tb_frame"
        ),
        F,
    ),
    (
        "exception_object_methods",
        body(
            "try:\n    get_area_to_sit_on('sofa_9')\nexcept Exception as e:\n    return e.with_traceback(None)"
        ),
        R,
    ),
    ("handle_private_state", body("c = get_character('Mia')\nreturn c._plans"), F),
    ("bound_method_self", body("return get_character('Mia').set_position.__self__"), F),
    ("tool_function_globals", body("return get_character.__globals__"), F),
    ("method_on_tool_function", body("return get_character.func_globals"), R),
    ("lambda_default_globals", body("f = lambda g=get_character: g.__globals__\nreturn f()"), F),
    (
        "default_arg_builtin_self",
        "def f(x=print):\n    return x.__self__\ndef parse_event():\n    return f()\n",
        F,
    ),
    ("private_namespace_name", body("return _secret"), F),
    ("dunder_builtins", body("return __builtins__"), F),
    (
        "main_guard",
        "def parse_event():\n    pass\nif __name__ == '__main__':\n    parse_event()\n",
        F,
    ),
    ("type_call", body("return type(1)"), F),
    ("vars_dir_globals", body("return vars(), dir(), globals()"), F),
    ("open_file", body("return open('/etc/passwd').read()"), F),
    ("eval_exec", body("return eval('1 + 1')"), F),
    ("with_statement", body("with open('x') as f:\n    pass"), F),
    ("class_definition", "class Evil:\n    pass\ndef parse_event():\n    pass\n", F),
    ("global_statement", "x = 1\ndef parse_event():\n    global x\n    x = 2\n", F),
    (
        "nonlocal_statement",
        "def parse_event():\n    x = 1\n    def g():\n        nonlocal x\n        x = 2\n    g()\n",
        F,
    ),
    ("decorator", "@print\ndef parse_event():\n    pass\n", F),
    ("yield_generator", body("yield 1"), F),
    ("async_def", "async def parse_event():\n    pass\n", F),
    ("raise_system_exit", body("raise SystemExit"), F),
    ("exit_call", body("exit()"), F),
    ("quit_call", body("quit()"), F),
    ("percent_format", body("return '%s %s' % (1, 2)"), F),
    ("match_statement", body("match 1:\n    case 1:\n        pass"), F),
    ("except_value_error", body("try:\n    pass\nexcept ValueError:\n    pass"), F),
    ("bytes_literal", body("return b'\\x00'"), F),
    ("keyword_underscore", body("return get_character(_name='x')"), F),
    ("kwargs_underscore", body("return get_character(**{'_name': 'x'})"), R),
    ("attribute_store", body("c = get_character('Mia')\nc.name = 'x'"), F),
    ("starred_unpack_function", body("a, *b = get_character"), R),
    # rebinding the spatial API
    ("rebind_tool", body("get_character = lambda n: None"), F),
    ("rebind_tool_top_level", "get_character = 1\ndef parse_event():\n    pass\n", F),
    ("shadow_tool_parameter", "def parse_event(get_character=1):\n    pass\n", F),
    ("del_tool_name", body("del get_character"), F),
    (
        "redefine_tool",
        "def get_character(name):\n    return name\ndef parse_event():\n    pass\n",
        F,
    ),
    ("for_target_tool", body("for get_state in range(2):\n    pass"), F),
    # hangs and bombs
    ("while_true", body("while True:\n    pass"), B),
    ("pow_tower", body("return 10**10**8"), B),
    ("str_repeat", body("return 'a' * 10**10"), B),
    ("list_repeat", body("return [0] * 10**9"), B),
    ("shift_bomb", body("return 1 << 10**9"), B),
    ("fstring_width", body("return f'{1:>{10**9}}'"), B),
    ("fstring_precision", body("return f'{1.5:.{10**6}f}'"), B),
    ("sum_huge_range", body("return sum(range(10**11))"), B),
    ("list_huge_range", body("return list(range(10**11))"), B),
    ("str_of_huge_int", body("return str(10**5000)"), B),
    ("int_of_long_string", body("return int('9' * 5000)"), B),
    ("deep_recursion", "def f(n):\n    return f(n + 1)\ndef parse_event():\n    return f(0)\n", B),
    (
        "mutual_recursion",
        "def a(n):\n    return b(n)\ndef b(n):\n    return a(n)\ndef parse_event():\n    return a(0)\n",
        B,
    ),
    ("lambda_self_application", body("f = lambda g: g(g)\nreturn f(f)"), B),
    ("nested_parentheses", "x = " + "(" * 1000 + "1" + ")" * 1000 + "\n", S),
    ("nested_lists", "x = " + "[" * 1000 + "]" * 1000 + "\n", S),
    ("deep_unary_chain", "x = " + "-" * 5000 + "1\n", B),
    ("long_binop_chain", "x = " + " + ".join(["1"] * 3000) + "\n", B),
    ("print_flood", body("while True:\n    print('spam')"), B),
    ("list_doubling", body("x = [0]\nwhile True:\n    x.extend(x)"), B),
    ("list_self_append", body("x = []\nwhile True:\n    x.append(x)"), B),
    ("string_doubling", body("s = 'x'\nwhile True:\n    s += s"), B),
    ("string_growth_slow", body("s = ''\nfor i in range(10**6):\n    s = s + 'abcdefghij'"), B),
    ("comprehension_memory", body("return [[0] * 20000 for _ in range(20000)]"), B),
    ("comprehension_product", body("return [1 for a in range(10**6) for b in range(10**6)]"), B),
    ("join_bomb", body("return ','.join(['a' * 20000] * 20000)"), B),
    ("replace_bomb", body("return ('a' * 20000).replace('a', 'aaaa')"), B),
    ("repr_bomb", body("x = ['a' * 10000] * 20000\nreturn str(x)"), B),
    (
        "shared_reference_repr",
        body("a = []\nfor i in range(40):\n    a = [a, a]\nreturn f'{a}'"),
        B,
    ),
    ("deep_compare", body("a = []\nb = []\na.append(a)\nb.append(b)\nreturn a == b"), B),
    ("deep_tuple_hash", body("t = ()\nfor i in range(15000):\n    t = (t,)\nreturn {t: 1}"), B),
    ("sorted_key_bomb", body("return sorted(range(100), key=lambda x: [0] * 10**9)"), B),
    (
        "finally_swallow_budget",
        body("try:\n    while True:\n        pass\nfinally:\n    return 1"),
        B,
    ),
    (
        "except_swallow_budget",
        body("try:\n    return 10**10**8\nexcept Exception:\n    return 1"),
        B,
    ),
    (
        "big_equality",
        body(
            "a = [[0] * 20000 for _ in range(20)]\nb = [[0] * 20000 for _ in range(20)]\nreturn a == b"
        ),
        B,
    ),
    ("big_membership", body("a = [[0] * 100] * 20000\nreturn [1] * 100 in a"), B),
    ("sort_nested_lists", body("a = [[i] * 1000 for i in range(1000)]\nreturn sorted(a)"), B),
    (
        "repeated_search",
        body("a = [(1, 2)] * 20000\nfor i in range(19000):\n    a.count((1, 3))"),
        B,
    ),
    (
        "dict_copy_bomb",
        body(
            "d = {i: i for i in range(15000)}\nkeep = []\nfor i in range(2000):\n    keep.append(d.copy())"
        ),
        B,
    ),
    (
        "hash_collision_set",
        body("return set([i * (2**61 - 1) for i in range(20000)])"),
        B,
    ),
    (
        "hash_collision_display",
        body("xs = [i * (2**61 - 1) for i in range(20000)]\nreturn {*xs}"),
        B,
    ),
    (
        "hash_collision_dict",
        body("return dict([(i * (2**61 - 1), 0) for i in range(20000)])"),
        B,
    ),
    (
        "hash_collision_union",
        body("a = {i * (2**61 - 1) for i in range(4000)}\nreturn a.union(a, a)"),
        B,
    ),
    ("range_index_float", body("return range(10**15).index(0.5)"), F),
    ("range_count_float", body("return range(10**15).count(0.5)"), F),
    ("range_slice_huge", body("return range(10**15)[::2]"), B),
    ("max_huge_range", body("return max(range(10**12))"), B),
    ("sorted_huge_range", body("return sorted(range(10**15))"), B),
    ("any_huge_range", body("return any(range(10**12))"), B),
    ("pow_three_args", body("return pow(2, 10**9, 7)"), F),
    ("divmod_huge", body("return divmod(2**4000, 3)"), F),
    ("bytes_call", body("return bytes(10**9)"), F),
    ("huge_tuple_key", body("return {tuple(range(5000)): 1}"), B),
    ("round_huge_ndigits", body("return round(5, -10**9)"), R),
    ("complex_result", body("return (-1) ** 0.5"), R),
    # bad values for tools
    (
        "nan_position",
        body("get_character('Mia').set_position([float('nan'), 0.0])"),
        ToolArgumentError,
    ),
    ("inf_position", body("get_character('Mia').set_position([1e309, -1e309])"), ToolArgumentError),
    ("unknown_object", body("return get_area_to_sit_on('chiar_1')"), UnknownObjectError),
    # garbage text
    ("syntax_garbage", "def parse_event(:\n    ))\n", S),
    ("binary_garbage", "\x00\x01\x02def", S),
    ("not_text", b"def parse_event():\n    pass\n", S),
    ("huge_source", "x = 1\n" * 10_000, B),
    ("break_outside_loop", body("break"), F),
    ("return_at_top_level", "return 1\n", F),
]


# `x in range(...)` for an item that is not an int: CPython compares it with every number
# of the range in C (no budget can stop that); the sandbox answers arithmetically.
RANGE_MEMBERSHIP: list[tuple[str, str, object]] = [
    ("half_in_huge_range", "0.5 in range(10**15)", False),
    ("str_in_huge_range", "'a' in range(10**12)", False),
    ("none_in_huge_range", "None in range(10**12)", False),
    ("list_in_huge_range", "[1] in range(10**12)", False),
    ("tuple_in_huge_range", "(1, 2) in range(10**12)", False),
    ("nan_in_huge_range", "float('nan') in range(10**15)", False),
    ("inf_in_huge_range", "float('inf') in range(10**15)", False),
    ("half_not_in_huge_range", "0.5 not in range(10**15)", True),
    ("whole_float_in_huge_range", "3.0 in range(1, 10**15, 2)", True),
    ("whole_float_off_step", "4.0 in range(1, 10**15, 2)", False),
    ("negative_float_in_range", "-2.0 in range(-10**15, 0)", True),
    ("big_float_outside_range", "1e300 in range(10**15)", False),
    ("int_in_huge_range", "10**14 in range(10**15)", True),
    ("bool_in_range", "True in range(10**15)", True),
]

"""A langgraph checkpoint written before the one installed name (issue 26) still resumes.

Its values name their pydantic classes by the old module paths (``agents.messages``,
``orchestrator.planning.state``). The serializer's allow-list holds the new names only, so
langgraph hands such a value back as its fields (never importing the old module) and the graph's
``PlanningState`` validates the fields into the class, as it does for every node's input; the
two readers of raw checkpoint values (the scene description in ``step_planner`` and
``plan_job``) validate a dict too.
"""

# ns-rewrite: skip-file (this file names the old module paths on purpose; the namespace rewrite
# script of issue 26 leaves it alone)
from __future__ import annotations

from typing import Any

import ormsgpack

from storyteller.agents.messages import HistoryEntry
from storyteller.orchestrator.planning.checkpoints import checkpoint_serializer
from storyteller.orchestrator.planning.state import PlanningState, RetryTurn
from tests.support.namespace_guard import second_names


def _renamed(blob: bytes, old: dict[str, str]) -> bytes:
    """``blob`` (msgpack with langgraph's extension values) with each class's module renamed."""

    def hook(code: int, data: bytes) -> ormsgpack.Ext:
        parts = ormsgpack.unpackb(data, ext_hook=hook, option=ormsgpack.OPT_NON_STR_KEYS)
        if isinstance(parts, list) and parts and isinstance(parts[0], str) and parts[0] in old:
            parts[0] = old[parts[0]]
        return ormsgpack.Ext(code, ormsgpack.packb(parts, option=ormsgpack.OPT_NON_STR_KEYS))

    value = ormsgpack.unpackb(blob, ext_hook=hook, option=ormsgpack.OPT_NON_STR_KEYS)
    return ormsgpack.packb(value, option=ormsgpack.OPT_NON_STR_KEYS)


OLD = {"storyteller.orchestrator.planning.state": "orchestrator.planning.state",
       "storyteller.agents.messages": "agents.messages"}


def _old_checkpoint_value(value: Any) -> tuple[str, bytes]:
    kind, blob = checkpoint_serializer().dumps_typed(value)
    assert kind == "msgpack"
    old = _renamed(blob, OLD)
    assert any(name.encode() in old for name in OLD.values()) and b"storyteller." not in old
    return kind, old


def test_an_old_checkpoint_value_comes_back_as_the_new_class() -> None:
    turns = (RetryTurn(reply="{", feedback="not JSON", error="ValueError"),)
    recent = (HistoryEntry(index=0, characters=("Ava",), activity="makes coffee", state="completed"),)
    serde = checkpoint_serializer()
    raw_turns = serde.loads_typed(_old_checkpoint_value(turns))
    assert not any(isinstance(t, RetryTurn) for t in raw_turns)  # blocked: the fields, not a class
    state = PlanningState(describer_turns=raw_turns, recent=serde.loads_typed(_old_checkpoint_value(recent)))
    assert state.describer_turns == turns and type(state.describer_turns[0]) is RetryTurn
    assert state.recent == recent and type(state.recent[0]) is HistoryEntry
    assert second_names() == []


def test_a_new_checkpoint_value_is_rebuilt_directly() -> None:
    turns = (RetryTurn(reply="{", feedback="not JSON"),)
    serde = checkpoint_serializer()
    assert tuple(serde.loads_typed(serde.dumps_typed(turns))) == turns

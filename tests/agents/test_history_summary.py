"""A long story's narrator history: the latest events listed, every event left out summarised in
one deterministic line (how many, and per character how many and the latest one's activity),
in a story session and in ``storyteller plan``'s graph; a short story's prompt is unchanged."""

from __future__ import annotations

import dataclasses
from typing import Any

from langgraph.checkpoint.memory import InMemorySaver

from storyteller.agents.history import HISTORY_WINDOW
from storyteller.agents.messages import CharacterStatus, EarlierEvents, HistoryEntry, PlanningFailure
from storyteller.agents.narrator import NarratorInput, history_text, narrator_messages
from storyteller.agents.prompt_templates import PromptLibrary
from storyteller.orchestrator.planning.checkpoints import StoryLog
from storyteller.orchestrator.planning.graph import compile_planning_graph, recursion_limit
from storyteller.orchestrator.planning.state import PlanningState
from storyteller.orchestrator.session.session_types import StoryEvent
from storyteller.orchestrator.session.story_history import history_window, story_history
from tests.support.planning_script import DESCRIPTION, PROGRAM, make_deps, narration
from tests.support.scripted_llm import ScriptedLLM

NAMES = ("Ava", "Ben", "Cleo")


def story(n: int) -> dict[str, StoryEvent]:
    """``n`` completed events: event i is NAMES[i % 3]'s (with Ava in every fifth too)."""
    out = {}
    for i in range(n):
        chars = (NAMES[i % 3], "Ava") if i % 5 == 0 and i % 3 else (NAMES[i % 3],)
        out[f"event-{i:04d}"] = StoryEvent(index=i, event_id=f"event-{i:04d}", characters=chars, activity=f"task {i}",
                                           requested_frame=i, applied_frame=i, state="completed")
    return out


def user_prompt(history: tuple[HistoryEntry, ...], earlier: EarlierEvents | None) -> str:
    inp = NarratorInput(scene_description="- room: table_1", characters=tuple(CharacterStatus(name=n) for n in NAMES),
                        instruction="", history=history, earlier=earlier)
    return narrator_messages(PromptLibrary(), inp)[1].content


def test_the_prompt_of_a_long_story_counts_and_summarises_every_event_left_out() -> None:
    history, earlier = history_window(story(500))
    assert [h.index for h in history] == list(range(500 - HISTORY_WINDOW, 500))
    assert earlier is not None and earlier.count == 500 - HISTORY_WINDOW
    text = user_prompt(history, earlier)
    # 488 before the window, and the window's 4 oldest completed ones (8 are listed)
    line = ("(earlier: 492 events not shown; Ava took part in 230, last: task 490; "
            "Ben took part in 164, last: task 490; Cleo took part in 164, last: task 491)")
    assert line in text.splitlines()
    assert "older completed events not shown" not in text
    assert "493. [completed] Ava: task 492" in text and "492. [completed]" not in text


def test_a_short_storys_prompt_is_unchanged() -> None:
    history, earlier = history_window(story(HISTORY_WINDOW))
    assert earlier is None and history == story_history(story(HISTORY_WINDOW))
    text = history_text(history)
    assert text.splitlines()[0] == "(4 older completed events not shown)" and "earlier" not in text
    assert history_text(history, earlier=None) == text


def test_steps_in_flight_and_failed_steps_take_their_place_in_the_window() -> None:
    events = story(20)
    failed = PlanningFailure(index=20, node="event_parser", attempts=4, feedback="no room",
                             event={"characters": ("Ben",), "activity": "dance"})
    pending = [HistoryEntry(index=21, characters=("Cleo",), activity="sing", state="ongoing")]
    history, earlier = history_window(events, [(20, failed)], pending)
    assert [h.index for h in history] == list(range(10, 22)) and history[-2].state == "failed"
    assert earlier is not None and earlier.count == 10
    assert [(c.name, c.events, c.last_activity) for c in earlier.characters] == [
        ("Ava", 5, "task 9"), ("Ben", 3, "task 7"), ("Cleo", 3, "task 8")
    ]


def test_fold_is_deterministic_and_keeps_first_appearance_order() -> None:
    first = EarlierEvents.fold(None, [(("Ben",), "a"), (("Ava", "Ben"), "b")])
    assert first == EarlierEvents.fold(None, [(("Ben",), "a"), (("Ava", "Ben"), "b")])
    again = EarlierEvents.fold(first, [(("Cleo",), "c"), (("Ava",), "d")])
    assert again is not None and again.count == 4
    assert [(c.name, c.events, c.last_activity) for c in again.characters] == [
        ("Ben", 2, "b"), ("Ava", 2, "d"), ("Cleo", 1, "c")
    ]
    assert EarlierEvents.fold(None, []) is None


async def test_the_planning_graph_summarises_the_events_its_window_drops() -> None:
    steps = 14
    port = ScriptedLLM({
        "describer": [DESCRIPTION],
        "narrator": [narration(["Ann"], f"eat {i}") for i in range(steps)],
        "event_parser": [PROGRAM.format(who="Ann")] * steps,
    })
    start: dict[str, Any] = PlanningState(
        instruction="", events_target=steps, roster=(CharacterStatus(name="Ann"),)
    ).model_dump()
    final = await compile_planning_graph(InMemorySaver()).ainvoke(
        start, config={"configurable": {"thread_id": "t"}, "recursion_limit": recursion_limit(steps, 3)},
        context=make_deps(port, StoryLog(":memory:", "t")), durability="sync",
    )
    assert final["earlier"] == EarlierEvents.fold(None, [(("Ann",), "eat 0"), (("Ann",), "eat 1")])
    narrator = [r.messages[1].content for r in port.requests if r.node == "narrator"]
    assert all("earlier" not in t for t in narrator[:13])
    assert "(earlier: 5 events not shown; Ann took part in 5, last: eat 4)" in narrator[13].splitlines()


def test_a_part_done_long_ago_stays_done_and_a_given_up_part_stays_given_up() -> None:
    """Hours into a story the instruction's first part is far behind the window: its event is
    kept for the instruction's progress (and only counted in the narrator's summary)."""
    from storyteller.agents.instruction_parts import PART_ATTEMPTS, instruction_progress, split_instruction

    instruction = "Ava makes coffee, then Ben dances."
    first, second = (p.text for p in split_instruction(instruction, NAMES, PromptLibrary()))
    events = story(60)
    done = dataclasses.replace(events["event-0003"], characters=("Ava",), activity="brew", part=first)
    events["event-0003"] = done
    fails = [
        (i, PlanningFailure(index=i, node="event_parser", attempts=1, feedback="no room", part=second,
                            event={"characters": ("Ben",), "activity": "dance"}))
        for i in (60, 61, 62)
    ]
    history, earlier = history_window(events, fails[:1], since=2)
    assert [h.index for h in history if h.part] == [3, 60]
    progress = instruction_progress(instruction, NAMES, history, free=NAMES, since=2)
    assert "[done]" in progress.text and "[failed]" not in progress.text  # one failure < PART_ATTEMPTS
    assert progress.next_part == second

    for i in range(63, 63 + 2 * HISTORY_WINDOW):  # the failures fall out of the window too
        events[f"event-{i:04d}"] = dataclasses.replace(events["event-0000"], index=i, event_id=f"event-{i:04d}")
    history, earlier = history_window(events, fails, since=2)
    assert [h.index for h in history if h.part] == [3, *range(63 - PART_ATTEMPTS, 63)]
    progress = instruction_progress(instruction, NAMES, history, free=NAMES, since=2)
    assert "[done]" in progress.text and "[failed]" in progress.text and progress.next_part is None
    assert earlier is not None and earlier.count == 63 + 2 * HISTORY_WINDOW - HISTORY_WINDOW - 3  # kept rows not folded
    text = user_prompt(history, earlier)
    assert "4. [completed] Ava: brew" not in text  # kept for the progress, not listed

    history, _ = history_window(events, fails, since=4)  # a later instruction: the old part is not its
    assert [h.index for h in history if h.part] == list(range(63 - PART_ATTEMPTS, 63))

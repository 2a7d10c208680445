"""The planning graph with a scripted LLM and a fake event-program runner (no model, no sim).

Also the durability test: a subprocess runs the graph on a SQLite checkpointer and is killed
(``os._exit``) the moment the event parser is called; the resumed run must not call the
narrator again.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
import textwrap
from pathlib import Path
from typing import Any

import pytest
from langchain_core.runnables import RunnableConfig
from langgraph.checkpoint.memory import InMemorySaver

from storyteller.agents.llm_port import LLMRequest, LLMResponse
from storyteller.agents.messages import CharacterStatus, ParsedEvent, PlanningFailure
from storyteller.orchestrator.planning.checkpoints import StoryLog, open_checkpointer
from storyteller.orchestrator.planning.graph import compile_planning_graph, recursion_limit, route_step
from storyteller.orchestrator.planning.state import PlanningState
from tests.support.planning_script import DESCRIPTION, PROGRAM, initial_state, make_deps, narration
from tests.support.scripted_llm import ScriptedLLM, choosing

REPO = Path(__file__).resolve().parents[3]


async def run_graph(port: ScriptedLLM, k: int, names: list[str], **kw: Any) -> tuple[dict[str, Any], StoryLog]:
    story = StoryLog(":memory:", "t1")
    graph = compile_planning_graph(InMemorySaver())
    final = await graph.ainvoke(
        initial_state(names, k),
        config={"configurable": {"thread_id": "t1"}, "recursion_limit": recursion_limit(k, 3)},
        context=make_deps(port, story, **kw),
        durability="sync",
    )
    return final, story


async def test_two_events_with_narrator_and_parser_feedback() -> None:
    port = ScriptedLLM({
        "describer": [DESCRIPTION],
        "narrator": [
            narration(["Zed"], "eat"),  # unknown character -> feedback
            narration(["Ann"], "eat at table_1"),
            narration(["Bob"], "eat at table_1"),
        ],
        "event_parser": [
            "I think Ann should sit.",  # no code -> feedback
            PROGRAM.replace("table_1", "tabel_1").format(who="Ann"),  # unknown object -> feedback
            PROGRAM.format(who="Ann"),
            PROGRAM.format(who="Bob"),
        ],
    })
    final, story = await run_graph(port, 2, ["Ann", "Bob"])
    events = story.events()
    assert [e.event.characters for e in events] == [("Ann",), ("Bob",)]
    assert events[0].narrator_attempts == 2 and events[0].parser_attempts == 3
    assert events[0].plans[0].action == "eat"
    # the feedback named the problems, in the conversation of the retries
    narrator_retry = port.requests[2]
    assert narrator_retry.node == "narrator" and "Zed is not a character" in narrator_retry.messages[-1].content
    parser_calls = [c for c in port.requests if c.node == "event_parser"]
    assert "no parse_event() function" in parser_calls[1].messages[-1].content
    assert "tabel_1" in parser_calls[2].messages[-1].content
    # the stable prefix is unchanged across retries (prefix cache)
    assert parser_calls[2].messages[:2] == parser_calls[0].messages[:2]
    assert final["step"] == 2 and final["llm_calls"] == len(port.requests)  # describer included
    assert PlanningState.model_validate(final).recent[-1].characters == ("Bob",)


async def test_retries_exhausted_is_a_failure_and_story_goes_on() -> None:
    port = ScriptedLLM({
        "describer": [DESCRIPTION],
        "narrator": [narration(["Zed"], "x")] * 3 + [narration(["Ann"], "eat")],
        "event_parser": [PROGRAM.format(who="Ann")],
    })
    _, story = await run_graph(port, 2, ["Ann"], max_retries=2)
    outcomes = story.outcomes()
    failure = outcomes[0][1]
    assert isinstance(failure, PlanningFailure) and failure.node == "narrator"
    assert failure.attempts == 3
    assert story.events()[0].event.characters == ("Ann",)


async def test_model_outage_fails_the_step_and_the_story_goes_on() -> None:
    from storyteller.agents.llm_port import LLMError, ReplayMissError

    outage = [LLMError("node event_parser: all 3 attempts failed (Timeout)")]

    class FlakyPort(ScriptedLLM):
        async def complete(self, request: LLMRequest) -> LLMResponse:
            if request.node == "event_parser" and outage:
                self.requests.append(request)
                raise outage.pop()
            return await super().complete(request)

    port = FlakyPort({
        "describer": [DESCRIPTION],
        "narrator": [narration(["Ann"], "eat"), narration(["Ann"], "eat")],
        "event_parser": [PROGRAM.format(who="Ann")],
    })
    _, story = await run_graph(port, 2, ["Ann"])
    first, second = story.outcomes()
    assert isinstance(first[1], PlanningFailure) and first[1].node == "event_parser"
    assert "Timeout" in first[1].feedback
    assert isinstance(second[1], ParsedEvent) and second[1].event.characters == ("Ann",)

    # a replay miss is not an outage: it stops the run
    class MissPort(ScriptedLLM):
        async def complete(self, request: LLMRequest) -> LLMResponse:
            if request.node == "narrator":
                raise ReplayMissError("replay miss for node narrator")
            return await super().complete(request)

    with pytest.raises(ReplayMissError):
        await run_graph(MissPort({"describer": [DESCRIPTION]}), 1, ["Ann"])


async def test_wait_and_busy_characters_are_not_offered() -> None:
    def narrator(req: LLMRequest) -> str:
        assert req.json_schema is not None, "the narrator's reply is schema-constrained"
        enum = req.json_schema["properties"]["event"]["properties"]["characters"]["items"]["enum"]
        return narration(enum[:1], "eat at table_1")

    def parser(req: LLMRequest) -> str:
        named = re.search(r'\["(\w+)"\]', req.messages[-1].content)
        assert named is not None, "the parser's prompt names the event's characters"
        return PROGRAM.format(who=named.group(1))

    port = ScriptedLLM({"describer": [DESCRIPTION], "narrator": narrator, "event_parser": parser})
    _, story = await run_graph(port, 3, ["Ann", "Bob"], busy_for_events=1)
    outcomes = story.outcomes()
    # Ann is busy during step 1, so Bob is planned; in step 2 Ann is free again
    assert [o.event.characters for _, o in outcomes if isinstance(o, ParsedEvent)] == [("Ann",), ("Bob",), ("Ann",)]
    assert all(isinstance(o, ParsedEvent) for _, o in outcomes)
    narrator_calls = [c for c in port.requests if c.node == "narrator"]
    assert "Ann: busy" in narrator_calls[1].messages[1].content


def test_route_step_ends_and_waits() -> None:
    s = PlanningState(events_target=1, step=1)
    assert route_step(s) == "__end__"
    s = PlanningState(events_target=2, step=0, roster=(CharacterStatus(name="A", busy=True),))
    assert route_step(s) == "record_outcome"


# ----- durability: kill after the narrator, resume, count calls ---------------------------
CHILD = textwrap.dedent(
    """
    import asyncio, os, sys
    sys.path.insert(0, {tests!r})
    sys.path.insert(0, {repo!r})
    from tests.support.scripted_llm import ScriptedLLM
    from tests.support.planning_script import DESCRIPTION, narration, make_deps, initial_state
    from storyteller.orchestrator.planning.checkpoints import StoryLog, open_checkpointer
    from storyteller.orchestrator.planning.graph import compile_planning_graph

    def die(req):
        os._exit(17)  # hard kill, no cleanup, the moment the parser is asked

    async def main():
        port = ScriptedLLM({{"describer": [DESCRIPTION], "narrator": [narration(["Ann"], "eat")], "event_parser": die}})
        async with open_checkpointer({db!r}) as saver:
            graph = compile_planning_graph(saver)
            await graph.ainvoke(initial_state(["Ann"], 1), config={{"configurable": {{"thread_id": "k"}}}},
                                context=make_deps(port, StoryLog({db!r}, "k")), durability="sync")

    asyncio.run(main())
    """
)


@pytest.mark.slow
async def test_killed_run_resumes_without_repeating_the_narrator(tmp_path: Path) -> None:
    db = tmp_path / "runs.sqlite"
    script = tmp_path / "child.py"
    script.write_text(CHILD.format(tests=str(REPO / "tests"), repo=str(REPO), db=str(db)))
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 17, proc.stderr

    port = ScriptedLLM({"describer": [], "narrator": [], "event_parser": [PROGRAM.format(who="Ann")]})
    story = StoryLog(db, "k")
    async with open_checkpointer(db) as saver:
        graph = compile_planning_graph(saver)
        config: RunnableConfig = {"configurable": {"thread_id": "k"}}
        snapshot = await graph.aget_state(config)
        assert snapshot.next == ("parse_event",)
        final = await graph.ainvoke(None, config=config, context=make_deps(port, story), durability="sync")
    assert port.count("narrator") == 0 and port.count("describer") == 0
    assert port.count("event_parser") == 1
    assert final["step"] == 1 and final["llm_calls"] == 3  # describer, narrator (before the kill), parser
    assert [e.event.characters for e in story.events()] == [("Ann",)]
    assert os.path.getsize(db) > 0


# ----- durability: kill during the describer's second attempt ------------------------------
CHILD_DESCRIBER = textwrap.dedent(
    """
    import asyncio, os, sys
    sys.path.insert(0, {tests!r})
    sys.path.insert(0, {repo!r})
    from tests.support.scripted_llm import ScriptedLLM
    from tests.support.planning_script import make_deps, initial_state
    from storyteller.orchestrator.planning.checkpoints import StoryLog, open_checkpointer
    from storyteller.orchestrator.planning.graph import compile_planning_graph

    replies = ['{{"areas": [{{"name": "dining", "purpose": "eat", "objects": ["table_1"]}}]}}']

    def describer(req):
        if replies:
            return replies.pop()  # incomplete: three objects missing -> feedback
        os._exit(17)  # hard kill the moment the describer is asked again

    async def main():
        port = ScriptedLLM({{"describer": describer}})
        async with open_checkpointer({db!r}) as saver:
            graph = compile_planning_graph(saver)
            await graph.ainvoke(initial_state(["Ann"], 1), config={{"configurable": {{"thread_id": "d"}}}},
                                context=make_deps(port, StoryLog({db!r}, "d")), durability="sync")

    asyncio.run(main())
    """
)


@pytest.mark.slow
async def test_killed_describer_retry_resumes_without_repeating_the_first_attempt(tmp_path: Path) -> None:
    db = tmp_path / "runs.sqlite"
    script = tmp_path / "child.py"
    script.write_text(CHILD_DESCRIBER.format(tests=str(REPO / "tests"), repo=str(REPO), db=str(db)))
    proc = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 17, proc.stderr

    port = ScriptedLLM({"describer": [DESCRIPTION], "narrator": [narration(["Ann"], "eat")],
                         "event_parser": [PROGRAM.format(who="Ann")]})
    story = StoryLog(db, "d")
    async with open_checkpointer(db) as saver:
        graph = compile_planning_graph(saver)
        config: RunnableConfig = {"configurable": {"thread_id": "d"}}
        snapshot = await graph.aget_state(config)
        assert snapshot.next == ("describe_scene",)
        assert len(snapshot.values["describer_turns"]) == 1  # the first attempt and its feedback survived
        final = await graph.ainvoke(None, config=config, context=make_deps(port, story), durability="sync")
    assert port.count("describer") == 1  # only the attempt that was cut off is made again
    retry = port.requests[0]
    assert retry.node == "describer" and len(retry.messages) == 4  # system, user, rejected reply, feedback
    assert "missing" in retry.messages[-1].content and "chair_1" in retry.messages[-1].content
    state = PlanningState.model_validate(final)
    assert state.description is not None and state.description.attempts == 2 and not state.description.repaired
    assert [e.event.characters for e in story.events()] == [("Ann",)]


async def test_describer_retries_exhausted_repairs_from_clusters() -> None:
    bad = '{"areas": [{"name": "dining", "purpose": "eat", "objects": ["table_1", "table_1"]}]}'
    port = ScriptedLLM({"describer": [bad, "not json", bad],
                         "narrator": [narration(["Ann"], "eat")], "event_parser": [PROGRAM.format(who="Ann")]})
    final, _ = await run_graph(port, 1, ["Ann"], max_retries=2)
    state = PlanningState.model_validate(final)
    assert port.count("describer") == 3
    assert state.description is not None and state.description.repaired and state.description.attempts == 3
    for name in ("table_1", "chair_1", "chair_2", "fridge_1"):
        assert state.description.text.count(name) == 1


async def test_requests_carry_the_step_frame_and_parsed_outputs_are_traced(tmp_path: Path) -> None:
    from storyteller.orchestrator.llm.trace_writer import TraceWriter
    from storyteller.orchestrator.llm.traces import read_trace

    class TracedPort(ScriptedLLM):
        """Numbers its answers like a trace-writing client (seqs of its own sink)."""

        def __init__(self, replies: dict[str, Any], trace: TraceWriter) -> None:
            super().__init__(replies)
            self.trace = trace

        async def complete(self, request: LLMRequest) -> LLMResponse:
            resp = await super().complete(request)
            return resp.model_copy(update={"trace_seq": self.trace.next_seq()})

    trace = TraceWriter(tmp_path / "t.jsonl", fsync="never")
    port = TracedPort({
        "describer": [DESCRIPTION],
        "narrator": [narration(["Zed"], "eat"), narration(["Ann"], "eat at table_1")],
        "event_parser": [PROGRAM.replace("table_1", "tabel_1").format(who="Ann"), PROGRAM.format(who="Ann")],
    }, trace)
    story = StoryLog(":memory:", "t1")
    graph = compile_planning_graph(InMemorySaver())
    start = PlanningState(instruction="Ann eats.", events_target=1, roster=(CharacterStatus(name="Ann"),),
                          sim_frame=42).model_dump()
    await graph.ainvoke(start, config={"configurable": {"thread_id": "t1"}, "recursion_limit": recursion_limit(1, 3)},
                        context=make_deps(port, story), durability="sync")
    trace.close()
    assert {c.sim_frame for c in port.requests} == {42}
    assert all(c.content_hash() == c.model_copy(update={"sim_frame": None}).content_hash() for c in port.requests)
    # seqs: run record 0, then each answer followed by its parsed record: describer 1,
    # narrator 3 and 5, parser 7 and 9
    assert story.trace_seqs(0) == (3, 5, 7, 9)
    parsed = {p.ref_seq: p for p in read_trace(tmp_path / "t.jsonl").records if p.kind == "parsed"}
    assert sorted(parsed) == [1, 3, 5, 7, 9]
    assert parsed[1].node == "describer" and parsed[1].ok
    assert parsed[3].node == "narrator" and parsed[3].error_type == "AnswerRejectedError"
    assert "Zed" in (parsed[3].error_message or "")
    assert parsed[5].parsed_output["event"] == {"characters": ["Ann"], "activity": "eat at table_1"}
    assert parsed[7].node == "event_parser" and parsed[7].error_type == "UnknownObjectError"
    (plan,) = parsed[9].parsed_output["plans"]
    assert plan["character"] == "Ann" and plan["action"] == "eat" and plan["area"] == "close to table_1"
    assert plan["position"] == [1.0, 1.0] and plan["facing"] == [0.0, 1.0]
    assert "def parse_event" in parsed[9].parsed_output["program"]


async def test_program_grammar_reaches_the_parser_request_only_when_asked() -> None:
    def port() -> ScriptedLLM:
        return ScriptedLLM({
            "describer": [DESCRIPTION],
            "narrator": [narration(["Ann"], "eat at table_1")],
            "event_parser": choosing([PROGRAM.format(who="Ann")]),
        })

    plain = port()
    await run_graph(plain, 1, ["Ann"])
    assert [c.grammar for c in plain.requests if c.node == "event_parser"] == [None]
    constrained = port()
    await run_graph(constrained, 1, ["Ann", "Bob"], program_grammar=True)
    (grammar,) = [c.grammar for c in constrained.requests if c.node == "event_parser" and c.choices is None]
    assert grammar is not None and 'get_character(\\"Ann\\")' in grammar and "block2" not in grammar
    assert '\\"table_1\\"' in grammar and '\\"Bob\\"' in grammar  # scene objects; Bob may be looked at
    assert all(c.grammar is None for c in constrained.requests if c.node != "event_parser")
    # eating is done sitting: the seat was chosen first (one of the two free chairs at the table)
    (choice,) = [c for c in constrained.requests if c.choices is not None]
    assert set(choice.choices or ()) == {"chair_1", "chair_2"}
    assert 'seat ::= "\\"chair_1\\""\n' in grammar


async def test_the_w_o_event_planner_decodes_under_the_open_grammar_when_asked() -> None:
    """The "w/o Event" ablation gets the same well-formed-program grammar as the event parser,
    with the free characters to pick from instead of an event's (busy Bob is not offered)."""
    from storyteller.orchestrator.planning.ablation_graph import Ablation, compile_graph

    for asked in (False, True):
        port = ScriptedLLM({"describer": [DESCRIPTION], "planner": [PROGRAM.format(who="Ann")]})
        story = StoryLog(":memory:", "t1")
        roster = (CharacterStatus(name="Ann"), CharacterStatus(name="Cy"), CharacterStatus(name="Bob", busy=True))
        state = PlanningState(instruction="Ann eats.", events_target=1, roster=roster).model_dump()
        await compile_graph(Ablation(planner="unified", description="describer"), InMemorySaver()).ainvoke(
            state, config={"configurable": {"thread_id": "t1"}, "recursion_limit": recursion_limit(1, 3)},
            context=make_deps(port, story, program_grammar=asked), durability="sync",
        )
        (grammar,) = [c.grammar for c in port.requests if c.node == "planner"]
        if not asked:
            assert grammar is None
            continue
        assert grammar is not None
        who = dict(line.split(" ::= ", 1) for line in grammar.strip().splitlines())["who"]
        assert who == '"\\"Ann\\"" | "\\"Cy\\""'
        assert story.events()[0].event.characters == ("Ann",)


async def test_sqlite_checkpoints_rebuild_our_types_without_warnings(tmp_path: Path, caplog: pytest.LogCaptureFixture) -> None:
    import logging

    from storyteller.orchestrator.planning.checkpoints import checkpoint_serializer
    from storyteller.orchestrator.planning.state import RetryTurn

    port = ScriptedLLM({"describer": [DESCRIPTION], "narrator": [narration(["Ann"], "eat at table_1")],
                         "event_parser": [PROGRAM.format(who="Ann")]})
    db = tmp_path / "runs.sqlite"
    story = StoryLog(db, "t1")
    config: RunnableConfig = {"configurable": {"thread_id": "t1"}, "recursion_limit": recursion_limit(1, 3)}
    async with open_checkpointer(db) as saver:
        graph = compile_planning_graph(saver)
        await graph.ainvoke(initial_state(["Ann"], 1), config=config, context=make_deps(port, story), durability="sync")
    caplog.set_level(logging.WARNING)
    async with open_checkpointer(db) as saver:
        snapshot = await compile_planning_graph(saver).aget_state(config)
    story.close()
    assert type(snapshot.values["description"]).__name__ == "SceneDescription"
    assert all(type(c).__name__ == "CharacterStatus" for c in snapshot.values["roster"])
    assert not [r for r in caplog.records if "unregistered" in r.getMessage()]
    # a type outside the allowlist is not rebuilt from a checkpoint
    serde = checkpoint_serializer()
    blob = serde.dumps_typed(RetryTurn(reply="r", feedback="f"))
    assert type(serde.loads_typed(blob)).__name__ == "RetryTurn"
    from pydantic import BaseModel

    class Foreign(BaseModel):
        a: int = 1

    assert serde.loads_typed(serde.dumps_typed(Foreign())) == {"a": 1}  # data only, no object built


async def test_the_rest_of_the_instruction_for_a_busy_character_is_a_wait_without_a_call() -> None:
    # "Ann eats, then chats with Bob": while Ann eats (busy for one step) the second part is
    # hers, so Bob's step is a wait with no narrator call (he is named: no bystander); then Ann
    # is free and takes part 2.
    port = ScriptedLLM({
        "describer": [DESCRIPTION],
        "narrator": [narration(["Ann"], "eat at table_1"), narration(["Ann"], "chat next to table_1")],
        "event_parser": [PROGRAM.format(who="Ann"), PROGRAM.format(who="Ann")],
    })
    story = StoryLog(":memory:", "t1")
    state = PlanningState(instruction="Ann eats, then chats with Bob.", events_target=3,
                          roster=(CharacterStatus(name="Ann"), CharacterStatus(name="Bob"))).model_dump()
    graph = compile_planning_graph(InMemorySaver())
    await graph.ainvoke(state, config={"configurable": {"thread_id": "t1"}, "recursion_limit": recursion_limit(3, 3)},
                        context=make_deps(port, story, busy_for_events=1), durability="sync")
    outcomes = [o for _, o in story.outcomes()]
    assert outcomes[1] is None  # the wait
    assert [o.event.characters for o in outcomes if isinstance(o, ParsedEvent)] == [("Ann",), ("Ann",)]
    assert all(o is None or isinstance(o, ParsedEvent) for o in outcomes)
    assert port.count("narrator") == 2
    second = [c for c in port.requests if c.node == "narrator"][1]
    assert "1) [done] Ann eats.\n2) [next] Then Ann chats with Bob." in second.messages[-1].content
    assert second.json_schema is not None
    assert second.json_schema["properties"]["event"]["properties"]["characters"]["items"]["enum"] == ["Ann"]


async def test_an_event_naming_some_of_a_parts_actors_takes_them_all() -> None:
    # "Ann and Bob eat": the narrator names Bob alone; the part is theirs together, so the event
    # (and the parser's prompt) has both, and it is marked as that part's.
    both = PROGRAM.format(who="Ann").removesuffix("\n```") + "\n" + "\n".join(
        PROGRAM.format(who="Bob").splitlines()[2:])
    port = ScriptedLLM({"describer": [DESCRIPTION], "narrator": [narration(["Bob"], "eat at table_1")],
                        "event_parser": [both]})
    story = StoryLog(":memory:", "t1")
    state = PlanningState(instruction="Ann and Bob eat at the table.", events_target=1,
                          roster=(CharacterStatus(name="Ann"), CharacterStatus(name="Bob"), CharacterStatus(name="Cy"))
                          ).model_dump()
    graph = compile_planning_graph(InMemorySaver())
    await graph.ainvoke(state, config={"configurable": {"thread_id": "t1"}, "recursion_limit": recursion_limit(1, 3)},
                        context=make_deps(port, story), durability="sync")
    (outcome,) = [o for _, o in story.outcomes()]
    assert isinstance(outcome, ParsedEvent) and outcome.event.characters == ("Ann", "Bob")
    assert outcome.part == "Ann and Bob eat at the table."
    parser = next(c for c in port.requests if c.node == "event_parser")
    assert "Ann" in parser.messages[-1].content and "Bob" in parser.messages[-1].content

"""The story a person reads is built from the applied plan (``storyteller.agents.story_text``): a phrase per
action label, objects by their human names (the id only where two objects share a label), the
narrator's words only where they agree with the plan, and a recorded run whose narrator says
something else than its plans tells the plans (live lines, ``story.md``, ``story.json``, viewer).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from typer.testing import CliRunner

from storyteller.agents.messages import Event, ParsedEvent, PlannedCharacter, PlanningFailure
from storyteller.agents.narrator_words import agrees, narration, with_names
from storyteller.agents.story_text import (
    PHRASES,
    ObjectNames,
    event_text,
    noun,
    place_text,
    plan_text,
    plural,
    step_text,
)
from storyteller.benchmark.support.fake_openai_server import FakeOpenAI
from storyteller.orchestrator.cli.app import app
from storyteller.orchestrator.session.run_report import story_markdown
from storyteller.orchestrator.viewer.run_folder import load_run
from storyteller.orchestrator.viewer.timeline import event_line
from storyteller.sim.motion.action_labels import ACTION_LABELS, ACTION_SPECS
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.model import Scene, SceneObject

HOME = load_bundled_scene("home")
OFFICE = load_bundled_scene("office")


def plan(who: str, action: str, area: str = "", seat: str | None = None, at: tuple[float, float] = (0.0, 0.0)) -> PlannedCharacter:
    return PlannedCharacter(character=who, action=action, area=area, position=at, facing=(1.0, 0.0), seat=seat)


def parsed(activity: str, *plans: PlannedCharacter) -> ParsedEvent:
    return ParsedEvent(index=0, event=Event(characters=tuple(p.character for p in plans), activity=activity), plans=plans)


# ----- phrases ------------------------------------------------------------------------------------
@pytest.mark.parametrize("label", ACTION_LABELS)
def test_every_action_label_has_a_phrase_that_says_it(label: str) -> None:
    assert label in PHRASES, f"no phrase for the action label {label!r}: add one to storyteller.agents.story_text.PHRASES"
    phrase = PHRASES[label]
    obj = "tv_1" if "tv" in label else "coffee_maker_1"
    sentence = plan_text(["Ava"], [plan("Ava", label, f"close to {obj}")], HOME)
    assert sentence.startswith("Ava ") and sentence.endswith(".") and "_" not in sentence, sentence
    assert agrees(sentence, [plan("Ava", label, f"close to {obj}")], HOME), sentence  # names its object and action
    assert agrees(phrase.does, [plan("Ava", label)], HOME), phrase.does  # the verb phrase alone says the action
    assert plural(phrase.does) != phrase.does, label  # "Ben and Cy chat", not "chats"
    if ACTION_SPECS[label].seatable:
        seated = plan_text(["Ava"], [plan("Ava", label, "sit on couch_1", seat="couch_1")], HOME)
        assert seated.startswith("Ava sits on the couch") and "couch_1" not in seated, seated


def test_a_label_without_a_phrase_would_fail_the_enumeration() -> None:
    assert set(PHRASES) == set(ACTION_LABELS)  # no stale phrases either


def test_the_issues_sentences() -> None:
    assert event_text(parsed("x", plan("Ava", "use_coffee_maker", "interact with coffee_maker_1")), HOME) == (
        "Ava makes coffee at the coffee maker."
    )
    assert event_text(parsed("x", plan("Ava", "drink", "sit on couch_1", seat="couch_1")), HOME) == (
        "Ava sits on the couch and drinks."
    )
    chat = parsed("x", plan("Ben", "chat", "close to water_dispenser_1"), plan("Cy", "chat", "close to water_dispenser_1"))
    assert event_text(chat, OFFICE) == "Ben and Cy chat by the water dispenser."


def test_characters_doing_the_same_are_grouped_and_partners_are_named() -> None:
    tv = parsed("x", plan("Ben", "watch_tv", "sit on couch_1", "couch_1"), plan("Cy", "watch_tv", "sit on couch_1", "couch_1"))
    assert event_text(tv, HOME) == "Ben and Cy sit on the couch and watch TV."
    apart = parsed("x", plan("Ben", "chat", "sit on armchair_1", "armchair_1"), plan("Cy", "chat", "close to tv_1"))
    assert event_text(apart, HOME) == "Ben and Cy chat, Ben on the armchair and Cy by the TV."
    mixed = parsed("x", plan("Ben", "turn_on_tv", "interact with tv_1"), plan("Cy", "sit_idle", "sit on couch_1", "couch_1"))
    assert event_text(mixed, HOME) == "Ben turns on the TV. Cy sits on the couch."
    hug = parsed("x", plan("Ben", "hug", "close to tv_1"), plan("Cy", "hug", "adjacent to couch_1"))
    assert event_text(hug, HOME) == "Ben and Cy hug, Ben by the TV and Cy next to the couch."
    meal = parsed("x", plan("Ava", "eat", "sit on chair_1", "chair_1"), plan("Ben", "eat", "sit on chair_2", "chair_2"))
    assert event_text(meal, HOME) == (
        "Ava and Ben eat, Ava on the chair by the coffee maker (chair_1) and Ben on the chair by the dishwasher (chair_2)."
    )
    three = parsed("x", plan("Ben", "watch_tv", "sit on couch_1", "couch_1"), plan("Cy", "watch_tv", "sit on couch_1", "couch_1"),
                   plan("Dan", "watch_tv", "sit on armchair_1", "armchair_1"))  # fmt: skip
    assert event_text(three, HOME) == "Ben, Cy and Dan watch TV, Ben and Cy on the couch and Dan on the armchair."
    lone = parsed("x", plan("Ben", "chat", "current position"), plan("Cy", "chat", "sit on couch_1", "couch_1"))
    assert event_text(lone, HOME) == "Ben chats with Cy. Cy sits on the couch and chats with Ben."


def test_areas_read_as_places() -> None:
    both = plan("Ava", "eat", "in front of tv_1 && close to couch_1")
    assert plan_text(["Ava"], [both], HOME) == "Ava eats in front of the TV and by the couch."
    couch = HOME.by_name["couch_1"].center
    either = plan("Ava", "read_book", "close to fridge_1 || close to couch_1", at=(couch[0], couch[1]))
    assert plan_text(["Ava"], [either], HOME) == "Ava reads a book by the couch."  # the alternative it stands in
    between = plan("Ava", "wave", "between tv_1 and couch_1")
    assert plan_text(["Ava"], [between], HOME) == "Ava waves between the TV and the couch."
    assert plan_text(["Ava"], [plan("Ava", "open_fridge", "interact with fridge_1")], HOME) == "Ava opens the fridge."
    assert plan_text(["Ava"], [plan("Ava", "drink", "current position")], HOME) == "Ava drinks."
    # the live view's place column
    assert place_text(plan("Ava", "drink", "sit on chair_5", "chair_5"), HOME) == "on the chair by the desk (chair_5)"
    assert place_text(plan("Ava", "use_coffee_maker", "interact with coffee_maker_1"), HOME) == "at the coffee maker"
    assert place_text(plan("Ava", "drink", "current position"), HOME) == "current position"


# ----- names ------------------------------------------------------------------------------------
def _box(name: str, x: float, y: float, size: tuple[float, float, float] = (0.5, 0.5, 0.9), z: float | None = None) -> SceneObject:
    label, _, idx = name.rpartition("_")
    return SceneObject(name=name, label=label, idx=int(idx), center=(x, y, size[2] / 2 if z is None else z), size=size,
                       sit_offset_vertical=0.45 if label == "chair" else 0.0)  # fmt: skip


TWO_CHAIRS = Scene(name="t", bounds_min=(0.0, 0.0), bounds_max=(10.0, 10.0), objects=(
    _box("chair_1", 1.0, 1.0), _box("window_1", 1.0, 0.1, (1.5, 0.1, 1.2)),
    _box("chair_2", 8.0, 8.0), _box("desk_1", 8.0, 9.0, (1.2, 0.6, 0.75)), _box("laptop_1", 8.0, 9.0, (0.3, 0.2, 0.03), 0.77),
    _box("chair_3", 5.0, 5.0), _box("lamp_1", 5.0, 9.9),
))  # fmt: skip


def test_a_shared_label_gets_a_landmark_and_its_id_a_unique_one_neither() -> None:
    names = ObjectNames(TWO_CHAIRS)
    assert names("chair_1") == "the chair by the window (chair_1)"
    assert names("chair_2") == "the chair by the desk (chair_2)"
    assert names("chair_3") == "the chair (chair_3)"  # no landmark within reach: the id tells it apart
    assert names("desk_1") == "the desk" and names("laptop_1") == "the laptop"
    sentence = plan_text(["Ava", "Ben"], [plan("Ava", "sit_idle", "sit on chair_1", "chair_1"),
                                          plan("Ben", "use_laptop", "interact with laptop_1")], TWO_CHAIRS)  # fmt: skip
    assert sentence == "Ava sits on the chair by the window (chair_1). Ben works on the laptop."


def test_landmarks_on_a_bundled_scene_tell_objects_apart() -> None:
    names = ObjectNames(HOME)
    assert names("chair_5") == "the chair by the desk (chair_5)"
    assert names("cabinet_1") == "the cabinet with the coffee maker (cabinet_1)"
    labelled: dict[str, list[str]] = {}
    for o in HOME.objects:
        shown = names(o.name)
        if names.unique(o.name):
            assert o.name not in shown and shown == f"the {noun(o.label)}"
        else:
            assert shown.endswith(f"({o.name})")
            labelled.setdefault(shown.rsplit(" (", 1)[0], []).append(o.name)
    # a landmark names one object of its label: the nearest to it
    assert all(len(v) == 1 for k, v in labelled.items() if " by the " in k or " with the " in k), labelled


def test_human_nouns() -> None:
    assert [noun(x) for x in ("coffee_maker", "tv", "tv_stand", "white_board", "dvd_player")] == [
        "coffee maker", "TV", "TV stand", "whiteboard", "DVD player"]  # fmt: skip


# ----- the narrator's words ---------------------------------------------------------------------
def test_the_narrators_words_are_shown_only_when_they_agree_with_the_plan() -> None:
    coffee = plan("Ava", "use_coffee_maker", "interact with coffee_maker_1")
    drink = plan("Ava", "drink", "sit on couch_1", "couch_1")
    wrong = "make coffee sitting on couch_1"  # the issue's run: the same words for both events
    assert narration(parsed(wrong, coffee), HOME) is None  # names no coffee maker
    assert narration(parsed(wrong, drink), HOME) is None  # the couch, but no drinking
    assert narration(parsed("brew a pot with coffee_maker_1", coffee), HOME) == "brew a pot with the coffee maker"
    assert narration(parsed("Sit on the couch and sip the coffee", drink), HOME) == "Sit on the couch and sip the coffee"
    assert with_names("sit on the chair_5", HOME) == "sit on the chair by the desk (chair_5)"
    both = parsed("use the coffee maker and drink on couch_1", coffee, plan("Ben", "drink", "sit on couch_1", "couch_1"))
    assert narration(both, HOME) is not None
    assert narration(parsed("use the coffee maker", coffee, plan("Ben", "drink", "sit on couch_1", "couch_1")), HOME) is None


def test_the_narrators_words_that_say_more_than_the_plan_are_not_shown() -> None:
    # From the recorded story suite (replayed at c842af8), each once shown beside its plan.
    tv = plan("Ben", "watch_tv", "close to tv_1")
    told = "switch TV on, curl up, and turn off TV, then watch a movie, and turn the set off again once the film is over"
    assert narration(parsed(told, tv), HOME) is None  # two other actions said by their own words
    assert narration(parsed("watch TV from the armchair", tv), HOME) is not None
    toaster = plan("Ava", "use_toaster", "interact with toaster_1")
    assert narration(parsed("put bread in toaster sitting on chair_1", toaster), HOME) is None  # she stands
    assert narration(parsed("make toast at toaster_1", toaster), HOME) == "make toast at the toaster"
    desks = [plan(n, "work_on_computer", f"sit on office_chair_{i}", f"office_chair_{i}") for i, n in enumerate(("Ava", "Ben"), 1)]
    listed = "work at desks_1, desk_2, desk_3, office_chair_1, office_chair_2, office_chair_3, office_chair_4, potted_"
    assert narration(parsed(listed, *desks), OFFICE) is None  # objects nobody is planned at
    assert narration(parsed("work at office_chair_1 and office_chair_2", *desks), OFFICE) is not None


def test_the_narrators_words_must_rank_the_planned_action() -> None:
    restaurant = load_bundled_scene("restaurant")
    phone = plan("Ava", "use_smartphone", "sit on bench_1", "bench_1")
    told = "bring coffee to Ben, who waits on the bench along the wall looking at his phone"
    assert narration(parsed(told, phone), restaurant) is None  # serving (or waiting), not her phone
    assert narration(parsed("look at a phone on the bench", phone), restaurant) is not None


def test_steps_without_an_event_have_text() -> None:
    assert "Nothing new starts" in step_text(None)
    failure = PlanningFailure(index=3, node="event_parser", attempts=4, feedback="f", event=Event(characters=("Ava", "Ben")))
    assert step_text(failure) == "No new event could be planned for Ava and Ben: the event parser gave up after 4 attempts."


# ----- story.md and the viewer from the payload -------------------------------------------------
def test_an_older_story_json_without_text_is_told_from_its_plans(tmp_path: Path) -> None:
    steps = [{"index": 0, "applied_frame": 3, "kind": "event", "characters": ["Ava"], "activity": "make coffee sitting on couch_1",
              "plans": [{"character": "Ava", "action": "drink", "area": "sit on couch_1", "position": [1.0, 2.0],
                         "facing": [1.0, 0.0], "seat": "couch_1"}]}]  # fmt: skip
    event = {"event_id": "event-0000", "index": 0, "characters": ["Ava"], "activity": "make coffee sitting on couch_1",
             "requested_frame": 3, "applied_frame": 3, "state": "ongoing", "finished_frame": None, "failure": None}  # fmt: skip
    story = {"scene": "home", "characters": ["Ava"], "instruction": "", "fps": 30, "frames": 90, "steps": steps,
             "events": [event]}  # fmt: skip
    md = story_markdown(story)
    assert "Ava sits on the couch and drinks\\." in md and "make coffee" not in md and "couch\\_1" not in md
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    run = load_run(folder)
    assert event_line(run.events[0], run.fps) == "  0.1 s  Ava sits on the couch and drinks."


def test_a_story_json_with_a_wait_and_a_failed_step_opens_in_the_viewer(tmp_path: Path) -> None:
    """The writer gives every step a ``text`` (a wait's too); the viewer's reader refused it as
    an unknown key, so ``view`` and the motion benchmark stopped on any run that had waited."""
    failure = PlanningFailure(index=1, node="event_parser", attempts=1, feedback="f", event=Event(characters=("Ava",)))
    steps = [{"index": 0, "applied_frame": 3, "kind": "wait", "text": step_text(None)},
             {"index": 1, "applied_frame": 9, "kind": "failed", "node": "event_parser", "feedback": "f",
              "text": step_text(failure)}]  # fmt: skip
    story = {"scene": "home", "characters": ["Ava"], "instruction": "", "fps": 30, "frames": 90, "steps": steps, "events": []}
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    assert load_run(folder).events == ()


# ----- a recorded run whose narrator contradicts its plans ----------------------------------------
COFFEE = (
    '```python\ndef parse_event():\n    a = get_character("Ava")\n'
    '    a.set_position(get_area_to_interact_with("coffee_maker_1"))\n'
    '    a.set_orientation("coffee_maker_1")\n    a.set_target_action("use_coffee_maker")\n```'
)
DRINK = (
    '```python\ndef parse_event():\n    a = get_character("Ava")\n'
    '    a.set_position(get_area_to_sit_on("couch_1"))\n    a.set_target_action("drink")\n```'
)
WRONG = json.dumps({"reasoning": "r", "event": {"characters": ["Ava"], "activity": "make coffee sitting on couch_1"}})


def prose(md: str) -> str:
    """story.md's story: its paragraphs before the detail section."""
    return md.split("\n## ", 1)[0]


@pytest.mark.slow
def test_a_run_whose_narrator_contradicts_its_plans_tells_the_plans(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("FAKE_PROVIDER_KEY", "sk-test-123")
    for var in ("STORYTELLER_CONFIG", "STORYTELLER_MODEL"):
        monkeypatch.delenv(var, raising=False)
    out = tmp_path / "out"
    with FakeOpenAI() as fake:
        fake.script["fake-narrator"] = [WRONG]
        fake.script["fake-parser"] = [COFFEE, DRINK]
        cfg = tmp_path / "fake.toml"
        cfg.write_text(
            f'[llm]\napi_base = "{fake.base}"\napi_key_env = "FAKE_PROVIDER_KEY"\n[llm.retry]\nmax_attempts = 1\n'
            '[nodes.narrator]\nmodel = "openai/fake-narrator"\n[nodes.event_parser]\nmodel = "openai/fake-parser"\n',
            encoding="utf-8",
        )
        result = CliRunner().invoke(app, ["run", "home", "--names", "Ava", "-d", "40", "--max-events", "2",
                                          "--description", "object-list", "--raw-feet", "--no-interactive",
                                          "--config", str(cfg), "--out", str(out)])  # fmt: skip
    assert result.exit_code == 0, result.stderr
    assert "event-0000 starts: Ava makes coffee at the coffee maker." in result.stdout
    assert "event-0000 done: Ava makes coffee at the coffee maker." in result.stdout
    assert "event-0001 starts: Ava sits on the couch and drinks." in result.stdout
    assert "make coffee sitting" not in result.stdout
    story = json.loads((out / "story.json").read_text(encoding="utf-8"))
    assert [e["text"] for e in story["events"]] == ["Ava makes coffee at the coffee maker.", "Ava sits on the couch and drinks."]
    assert [e["activity"] for e in story["events"]] == ["make coffee sitting on couch_1"] * 2  # kept as data
    assert [e["narration"] for e in story["events"]] == [None, None]
    md = (out / "story.md").read_text(encoding="utf-8")
    told = prose(md)
    assert "Ava makes coffee at the coffee maker\\." in told and "Ava sits on the couch and drinks\\." in told
    assert "make coffee sitting" not in md
    ids = [re.escape(o.name).replace("_", r"\\?_") for o in HOME.objects if ObjectNames(HOME).unique(o.name)]
    assert not [i for i in ids if re.search(rf"\b{i}\b", told)]  # no raw id of a uniquely named object
    run = load_run(out)
    assert [event_line(e, run.fps).split(" s  ", 1)[1] for e in run.events] == [
        "Ava makes coffee at the coffee maker. (done)", "Ava sits on the couch and drinks. (done)"]  # fmt: skip


def test_the_fidelity_check_finds_a_text_that_misses_its_plan_and_a_raw_id(tmp_path: Path) -> None:
    from storyteller.benchmark.story_text_fidelity import check_run

    steps = [{"index": i, "applied_frame": i, "kind": "event", "characters": ["Ava"], "activity": "a",
              "plans": [{"character": "Ava", "action": "drink", "area": "sit on couch_1", "position": [1.0, 2.0],
                         "facing": [1.0, 0.0], "seat": "couch_1"}]} for i in (0, 1)]  # fmt: skip
    events = [{"event_id": f"event-000{i}", "index": i, "characters": ["Ava"], "activity": "a", "requested_frame": i,
               "applied_frame": i, "state": "ongoing", "finished_frame": None, "failure": None, "text": text}
              for i, text in enumerate(["Ava sits on the couch and drinks.", "Ava makes coffee sitting on couch_1."])]  # fmt: skip
    story = {"scene": "home", "characters": ["Ava"], "instruction": "", "fps": 30, "frames": 9, "steps": steps, "events": events}
    folder = tmp_path / "run"
    folder.mkdir()
    (folder / "story.json").write_text(json.dumps(story), encoding="utf-8")
    (folder / "story.md").write_text(story_markdown(story), encoding="utf-8")
    check = check_run(folder)
    assert (check.events, check.faithful) == (2, 1) and check.misses[0].startswith("event-0001")
    assert check.raw_ids == ["couch_1"]  # written as couch\_1 in the prose


def test_story_md_says_waits_once_per_run_and_not_beside_a_starting_event() -> None:
    plans = [{"character": "Ava", "action": "drink", "area": "sit on couch_1", "position": [1.0, 2.0],
              "facing": [1.0, 0.0], "seat": "couch_1"}]  # fmt: skip
    steps = [{"index": 0, "applied_frame": 30, "kind": "event", "characters": ["Ava"], "activity": "a", "plans": plans},
             {"index": 1, "applied_frame": 30, "kind": "wait", "text": step_text(None)},
             {"index": 2, "applied_frame": 60, "kind": "wait", "text": step_text(None)},
             {"index": 3, "applied_frame": 90, "kind": "wait", "text": step_text(None)}]  # fmt: skip
    event = {"event_id": "event-0000", "index": 0, "characters": ["Ava"], "activity": "a", "requested_frame": 30,
             "applied_frame": 30, "state": "completed", "finished_frame": 120, "failure": None,
             "text": "Ava sits on the couch and drinks."}  # fmt: skip
    md = story_markdown({"scene": "home", "characters": ["Ava"], "instruction": "", "fps": 30, "frames": 150,
                         "steps": steps, "events": [event]})  # fmt: skip
    assert md.count("Nothing new starts") == 1 and "\n00:02.0 \u2014 Nothing new starts" in md
    assert md.index("Ava sits on the couch") < md.index("Nothing new starts")

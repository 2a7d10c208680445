"""An event about a device someone else is using alone, or about sitting at a place whose seats
are all taken: its characters wait for it (storyteller.agents.device_in_use, applied by the planning graph's
check_program)."""

from __future__ import annotations

import math

from storyteller.agents.device_in_use import busy_device, full_place, waiting_for_busy_device
from storyteller.agents.messages import PlannedCharacter
from storyteller.sim.scene.bundled import resolve_scene
from storyteller.sim.scene.model import Scene
from storyteller.tools.character_states import CharacterState, WorldView
from tests.support.scene_objects import box

HOME = resolve_scene("home")
DALIA_AT_FRIDGE = CharacterState(name="Dalia", position=(0.9, 0.9), action="open_fridge", busy=True)
LUCA = CharacterState(name="Luca", position=(3.0, 3.0))
ON_CHAIR = PlannedCharacter(character="Luca", action="drink", area="sit on chair_3", position=(1.8, 3.3),
                            facing=(0.0, 1.0), seat="chair_3")
STANDING = PlannedCharacter(character="Luca", action="drink", area="close to table_1", position=(3.0, 2.0),
                            facing=(1.0, 0.0))


def world(*characters: CharacterState) -> WorldView:
    return WorldView(characters=characters)


def test_words_about_a_device_in_use_make_a_plan_that_avoids_it_a_wait() -> None:
    text = "Luca also has to fetch a carton of juice from the fridge."
    busy = world(DALIA_AT_FRIDGE, LUCA)
    assert busy_device(text, [ON_CHAIR], busy, HOME, ["Luca"]) == "fridge_1"
    seated, standing = waiting_for_busy_device(text, [ON_CHAIR, STANDING], busy, HOME, ["Luca"])
    assert seated.action == "idle" and seated.seat == "chair_3" and seated.facing == ON_CHAIR.facing
    assert standing.action == "idle" and standing.position == STANDING.position
    fridge = HOME.by_name["fridge_1"].center
    toward = (fridge[0] - 3.0, fridge[1] - 2.0)
    assert math.isclose(standing.facing[0] * toward[1] - standing.facing[1] * toward[0], 0.0, abs_tol=1e-9)
    assert "waiting for fridge_1" in standing.area


def test_a_free_device_a_landmark_or_a_plan_that_uses_it_change_nothing() -> None:
    text = "Luca also has to fetch a carton of juice from the fridge."
    assert busy_device(text, [ON_CHAIR], world(LUCA), HOME, ["Luca"]) is None  # nobody at the fridge
    idle_dalia = DALIA_AT_FRIDGE.model_copy(update={"busy": False, "action": "idle"})
    assert busy_device(text, [ON_CHAIR], world(idle_dalia, LUCA), HOME, ["Luca"]) is None
    busy = world(DALIA_AT_FRIDGE, LUCA)
    assert busy_device("Luca waits by the fridge.", [ON_CHAIR], busy, HOME, ["Luca"]) is None  # where, not what
    at_fridge = PlannedCharacter(character="Luca", action="open_fridge", area="in front of fridge_1",
                                 position=(0.9, 1.0), facing=(0.0, -1.0))
    assert busy_device(text, [at_fridge], busy, HOME, ["Luca"]) is None  # the spatial API's check decides
    assert busy_device(text, [ON_CHAIR], busy, HOME, ["Luca", "Dalia"]) is None  # the user is in the event
    assert waiting_for_busy_device("Luca reads.", [ON_CHAIR], busy, HOME, ["Luca"]) == (ON_CHAIR,)


def kiosk() -> Scene:
    """A counter with two stools (stool_1, stool_2) and, 4 m off, a table with two chairs."""
    return Scene(name="kiosk", bounds_min=(-3.0, -3.0), bounds_max=(8.0, 5.0), objects=(
        box("counter", 1, 0.0, 0.0, size=(2.0, 0.6, 1.05)),
        box("stool", 1, -0.5, -0.6, seat=True, size=(0.4, 0.4, 0.75)),
        box("stool", 2, 0.5, -0.6, seat=True, size=(0.4, 0.4, 0.75)),
        box("table", 1, 4.0, 0.0, size=(1.2, 0.8, 0.75)),
        box("chair", 1, 3.7, -0.7, seat=True), box("chair", 2, 4.3, -0.7, seat=True),
    ))  # fmt: skip


KIOSK = kiosk()
AT_TABLE = PlannedCharacter(character="Noor", action="order_drink", area="sit on chair_1", position=(3.7, -0.7),
                            facing=(0.0, 1.0), seat="chair_1")


def test_sitting_at_a_place_whose_seats_are_all_taken_is_a_wait() -> None:
    text = "Noor wants to order a tea at the counter."
    assert full_place(text, [AT_TABLE], KIOSK, free_seats=["chair_1", "chair_2"]) == "counter_1"
    (waiting,) = waiting_for_busy_device(text, [AT_TABLE], world(), KIOSK, ["Noor"], ["chair_1", "chair_2"])
    assert waiting.action == "idle" and waiting.seat == "chair_1" and "waiting for counter_1" in waiting.area


def test_a_free_seat_at_the_place_a_plan_there_standing_or_a_landmark_change_nothing() -> None:
    text = "Noor wants to order a tea at the counter."
    assert full_place(text, [AT_TABLE], KIOSK, free_seats=["stool_2", "chair_1"]) is None  # a stool is left
    on_stool = AT_TABLE.model_copy(update={"seat": "stool_1", "area": "sit on stool_1"})
    assert full_place(text, [on_stool], KIOSK, free_seats=["chair_1"]) is None  # she sits there
    standing = AT_TABLE.model_copy(update={"seat": None, "action": "clean_table", "area": "close to counter_1"})
    assert full_place("Noor wipes down the counter.", [standing], KIOSK, free_seats=[]) is None  # not sitting
    assert full_place("Noor sits as far from the counter as she can.", [AT_TABLE], KIOSK, free_seats=[]) is None
    assert full_place("Noor reads a paper.", [AT_TABLE], KIOSK, free_seats=[]) is None  # no place named
    # the unchanged plans when nothing is full, and without the free seats (the device rule alone)
    assert waiting_for_busy_device("Noor orders at the counter.", [AT_TABLE], world(), KIOSK, ["Noor"]) == (AT_TABLE,)

"""An event about a device someone else is using alone: its characters wait for it
(agents.device_in_use, applied by the planning graph's check_program)."""

from __future__ import annotations

import math

from agents.device_in_use import busy_device, waiting_for_busy_device
from agents.messages import PlannedCharacter
from sim.scene.bundled import resolve_scene
from tools.character_states import CharacterState, WorldView

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

# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 60 (House): "Theodore stands in front of the refrigerator."
def parse_event():
    theodore = get_character("Theodore")
    # the refrigerator of the House scene is fridge_1
    theodore.set_position(get_area_in_front_of("fridge_1"))
    theodore.set_orientation("fridge_1")
    theodore.set_target_action("idle")
    return [theodore]

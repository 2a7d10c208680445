# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 67 (Restaurant): "Robert stands behind the reception desk."
def parse_event():
    robert = get_character("Robert")
    robert.set_position(get_area_behind("reception_desk_1"))
    robert.set_orientation("reception_desk_1")
    robert.set_target_action("idle")
    return [robert]

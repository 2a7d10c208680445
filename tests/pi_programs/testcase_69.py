# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 69 (House): "Charles stands behind the chair_1."
def parse_event():
    charles = get_character("Charles")
    charles.set_position(get_area_behind("chair_1"))
    charles.set_target_action("idle")
    return [charles]

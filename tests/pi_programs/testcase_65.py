# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 65 (Office): "Jerry stands right to the cabinet_2."
def parse_event():
    jerry = get_character("Jerry")
    jerry.set_position(get_area_right_of("cabinet_2"))
    jerry.set_target_action("idle")
    return [jerry]

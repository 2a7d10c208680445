# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 64 (Office): "Scott stands left of the water dispenser."
def parse_event():
    scott = get_character("Scott")
    # the Office scene has one water dispenser
    scott.set_position(get_area_left_of("water_dispenser_1"))
    scott.set_target_action("idle")
    return [scott]

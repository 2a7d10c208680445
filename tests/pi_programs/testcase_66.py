# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 66 (Restaurant): "Jacob stands to the left of the bar counter."
def parse_event():
    jacob = get_character("Jacob")
    jacob.set_position(get_area_left_of("bar_counter_1"))
    jacob.set_target_action("idle")
    return [jacob]

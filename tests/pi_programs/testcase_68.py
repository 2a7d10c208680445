# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 68 (Restaurant): "Robert stands right next to the table_5."
def parse_event():
    robert = get_character("Robert")
    robert.set_position(get_area_adjacent_to("table_5"))
    robert.set_target_action("idle")
    return [robert]

# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 61 (House): "Franklin makes coffee using coffee maker."
def parse_event():
    franklin = get_character("Franklin")
    # stand where the coffee maker can be used, facing it
    franklin.set_position(get_area_to_interact_with("coffee_maker_1"))
    franklin.set_orientation("coffee_maker_1")
    franklin.set_target_action("use_coffee_maker")
    return [franklin]

# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 62 (House): "Benjamin turns on the record player."
def parse_event():
    benjamin = get_character("Benjamin")
    player = "record_player_1"
    benjamin.set_position(get_area_to_interact_with(player))
    benjamin.set_orientation(player)
    benjamin.set_target_action("turn_on_record_player")
    return [benjamin]

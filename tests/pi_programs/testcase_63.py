# ruff: noqa: F821  (an event program: the sandbox provides the spatial-API names)
# Reference PI case 63 (Office): "Douglas stands between the couch_1 and couch_3"
def parse_event():
    douglas = get_character("Douglas")
    douglas.set_position(get_area_between("couch_1", "couch_3"))
    douglas.set_target_action("idle")
    return [douglas]

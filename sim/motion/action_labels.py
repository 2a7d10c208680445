"""Action labels the simulation can animate, each with its family, looping and timing.

The labels cover every ``action_labels`` entry of the 40 reference benchmark cases plus the
motion-only labels the simulation needs itself (``walk``, ``sit_down``, ``sit_idle``,
``stand_up``, ``wave``, ``hug``).

Families decide which motion-matching features a label's database uses:

- ``locomotion``: walking, turns, starts and stops, matched on a future trajectory;
- ``sitting``: sitting down, sitting still, standing up, matched relative to the seat;
- ``partner``: actions done with another character (chat, handshake, hug, dance...), matched
  relative to the partner (or the group centre);
- ``in_place``: actions on an object or with a prop (drink, use an appliance, read...);
- ``idle``: standing still.

Whether an in-place or partner action is done seated is decided by the area the event
program chose (``sit on chair_2``), not by the label: labels with ``seatable=True`` have a
seated variant whose database key is ``database_key(label, seated=True)``.

A *looping* action (watch TV, chat, dance) repeats until the story interrupts it; a
*completing* action (turn on the TV, open the fridge) ends after ``duration_s`` seconds.
"""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import Literal

ActionFamily = Literal["locomotion", "sitting", "partner", "in_place", "idle"]
ACTION_FAMILIES: tuple[ActionFamily, ...] = ("locomotion", "sitting", "partner", "in_place", "idle")

# How a procedural clip moves the hands; see sim/motion/sources/procedural_actions.py.
Gesture = Literal[
    "none",
    "reach",  # reach forward to an object at ``reach_height`` and manipulate it
    "reach_low",  # bend down to a low object (dishwasher, low cabinet)
    "to_mouth",  # one hand to the mouth (drink)
    "to_mouth_both",  # alternate hands to the mouth (eat)
    "hold_chest",  # both hands hold a prop at the chest, head down (phone, book)
    "type",  # both hands typing at ``reach_height``
    "wipe",  # one hand wipes a surface in circles at ``reach_height``
    "write",  # one hand draws on a vertical board at ``reach_height``
    "wave",
    "talk",  # conversational hand gestures and nods
    "listen",  # still, small nods, hands low
    "handshake",
    "hug",
    "dance",
    "carry",  # hold a tray / plate in front at waist height and set it down
]

SEATED_SUFFIX = "@seated"


@dataclass(frozen=True)
class ActionSpec:
    """What the simulation knows about one action label.

    duration_s: nominal duration in seconds of one completion (completing actions) or one
    cycle of the procedural clip (looping actions). reach_height: height above the floor in
    metres of the hands' working point for standing use (seated variants use table height).
    """

    label: str
    family: ActionFamily
    loops: bool
    duration_s: float
    seatable: bool
    gesture: Gesture
    reach_height: float = 1.0
    description: str = ""


def _spec(
    label: str,
    family: ActionFamily,
    loops: bool,
    duration_s: float,
    gesture: Gesture,
    *,
    seatable: bool = False,
    reach_height: float = 1.0,
    description: str = "",
) -> ActionSpec:
    return ActionSpec(label, family, loops, duration_s, seatable, gesture, reach_height, description)


_SPECS: tuple[ActionSpec, ...] = (
    # motion-only labels
    _spec("walk", "locomotion", True, 1.0, "none", description="walk, turn, start and stop"),
    _spec("idle", "idle", True, 4.0, "none", seatable=True, description="stand or sit still"),
    _spec("sit_down", "sitting", False, 2.0, "none", description="sit down on a seat behind"),
    _spec("sit_idle", "sitting", True, 4.0, "none", description="sit still"),
    _spec("stand_up", "sitting", False, 1.8, "none", description="stand up from a seat"),
    # partner actions
    _spec("chat", "partner", True, 4.0, "talk", seatable=True),
    _spec("discuss", "partner", True, 4.0, "talk", seatable=True),
    _spec("attend_meeting", "partner", True, 4.0, "listen", seatable=True),
    _spec("handshake", "partner", False, 3.0, "handshake"),
    _spec("hug", "partner", False, 3.5, "hug"),
    _spec("dance", "partner", True, 4.0, "dance"),
    # in-place actions with props or the body only
    _spec("drink", "in_place", False, 4.0, "to_mouth", seatable=True),
    _spec("eat", "in_place", True, 4.0, "to_mouth_both", seatable=True),
    _spec("use_smartphone", "in_place", True, 4.0, "hold_chest", seatable=True),
    _spec("read_book", "in_place", True, 4.0, "hold_chest", seatable=True),
    _spec("use_laptop", "in_place", True, 4.0, "type", seatable=True, reach_height=0.95),
    _spec("work_on_computer", "in_place", True, 4.0, "type", seatable=True, reach_height=0.95),
    _spec("watch_tv", "in_place", True, 4.0, "listen", seatable=True),
    _spec("listen_to_music", "in_place", True, 4.0, "listen", seatable=True),
    _spec("wave", "in_place", False, 3.0, "wave"),
    # appliances and furniture
    _spec("turn_on_tv", "in_place", False, 2.5, "reach", reach_height=0.8),
    _spec("turn_off_tv", "in_place", False, 2.5, "reach", reach_height=0.8),
    _spec("turn_on_record_player", "in_place", False, 3.0, "reach", reach_height=0.85),
    _spec("turn_off_record_player", "in_place", False, 3.0, "reach", reach_height=0.85),
    _spec("open_fridge", "in_place", False, 2.5, "reach", reach_height=1.1),
    _spec("close_fridge", "in_place", False, 2.5, "reach", reach_height=1.1),
    _spec("open_cabinet", "in_place", False, 2.5, "reach", reach_height=0.9),
    _spec("close_cabinet", "in_place", False, 2.5, "reach", reach_height=0.9),
    _spec("use_coffee_maker", "in_place", False, 6.0, "reach", reach_height=1.05),
    _spec("use_toaster", "in_place", False, 5.0, "reach", reach_height=1.0),
    _spec("use_microwave", "in_place", False, 5.0, "reach", reach_height=1.15),
    _spec("use_dishwasher", "in_place", False, 6.0, "reach_low", reach_height=0.55),
    _spec("use_water_dispenser", "in_place", False, 5.0, "reach", reach_height=1.0),
    _spec("take_out_drink", "in_place", False, 3.0, "reach", reach_height=1.0),
    _spec("take_out_document", "in_place", False, 3.0, "reach", reach_height=1.0),
    _spec("take_out_book", "in_place", False, 3.0, "reach", reach_height=1.2),
    _spec("clean_white_board", "in_place", False, 6.0, "wipe", reach_height=1.45),
    _spec("write_on_white_board", "in_place", False, 6.0, "write", reach_height=1.45),
    _spec("clean_table", "in_place", False, 6.0, "wipe", reach_height=0.8),
    # restaurant roles
    _spec("deliver_menu", "in_place", False, 3.0, "carry", reach_height=0.8),
    _spec("serve_food", "in_place", False, 3.0, "carry", reach_height=0.8),
    _spec("serve_drink", "in_place", False, 3.0, "carry", reach_height=0.8),
    _spec("take_order", "in_place", False, 5.0, "hold_chest"),
    _spec("order_food", "in_place", False, 4.0, "talk", seatable=True),
    _spec("order_drink", "in_place", False, 4.0, "talk", seatable=True),
    _spec("pay_bill", "in_place", False, 4.0, "reach", seatable=True, reach_height=0.85),
)

ACTION_SPECS: dict[str, ActionSpec] = {s.label: s for s in _SPECS}
ACTION_LABELS: tuple[str, ...] = tuple(ACTION_SPECS)


class UnknownActionLabelError(ValueError):
    """A label that no motion database covers; the message suggests the closest labels."""

    def __init__(self, label: str) -> None:
        close = difflib.get_close_matches(label, ACTION_LABELS, n=3, cutoff=0.5)
        hint = f"; did you mean {', '.join(repr(c) for c in close)}?" if close else ""
        super().__init__(f"unknown action label {label!r}{hint}")
        self.label = label
        self.suggestions = tuple(close)


def action_spec(label: str) -> ActionSpec:
    """The spec of ``label`` (a plain label, or a database key with the seated suffix)."""
    base = label.removesuffix(SEATED_SUFFIX)
    spec = ACTION_SPECS.get(base)
    if spec is None:
        raise UnknownActionLabelError(label)
    if label.endswith(SEATED_SUFFIX) and not spec.seatable:
        raise UnknownActionLabelError(label)
    return spec


def family_of(label: str) -> ActionFamily:
    """Family of a label or database key; seated variants match relative to the seat."""
    spec = action_spec(label)
    return "sitting" if label.endswith(SEATED_SUFFIX) else spec.family


def is_seated_key(key: str) -> bool:
    return key.endswith(SEATED_SUFFIX)


def database_key(label: str, seated: bool = False) -> str:
    """Name of the motion database that animates ``label`` (standing or seated).

    Seated idle is the ``sit_idle`` database; other seatable labels get ``<label>@seated``.
    Raises UnknownActionLabelError for unknown labels and for seated non-seatable labels.
    """
    key = _database_key_or_none(label, seated)
    if key is None:
        action_spec(label)  # an unknown label: its own message
        raise UnknownActionLabelError(f"{label}{SEATED_SUFFIX}")
    return key


def _database_key_or_none(label: str, seated: bool) -> str | None:
    """``database_key(label, seated)``, or None where that raises. No error is built: its
    message looks for close labels with difflib, about 1 ms a label, and the program grammars
    ask this of every offered label for every planning step."""
    spec = ACTION_SPECS.get(label.removesuffix(SEATED_SUFFIX))
    if spec is None or (label.endswith(SEATED_SUFFIX) and not spec.seatable):
        return None
    if not seated or spec.family == "sitting":
        return spec.label
    if spec.label == "idle":
        return "sit_idle"
    if not spec.seatable:
        return None
    return f"{spec.label}{SEATED_SUFFIX}"


def playable_seated(label: str) -> bool:
    """Whether ``label`` has a seated motion (False for unknown labels)."""
    return _database_key_or_none(label, seated=True) is not None


def all_database_keys() -> tuple[str, ...]:
    """Every database key: each label plus the seated variants of seatable labels."""
    keys = list(ACTION_LABELS)
    keys += [f"{s.label}{SEATED_SUFFIX}" for s in _SPECS if s.seatable and s.label != "idle"]
    return tuple(keys)

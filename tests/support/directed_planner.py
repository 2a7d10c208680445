"""A scripted unified planner that follows the latest instruction, for the instruction-box tests
(``tests/orchestrator/viewer/test_viewer_director.py``) against the fake OpenAI server: while the request's
instruction asks for toast, a free Max makes it at the toaster; otherwise the first free
character does its everyday task (``tests.support.story_planner.first_free``). Answers by
request content only, so a replay or a resume gets the same answers.
"""

from __future__ import annotations

import re
from typing import Any

from tests.support.story_planner import first_free, interact_program

TOAST = "Max makes toast"
"""The instruction the tests type."""
TOASTER = ("toaster_1", "use_toaster")
"""What Max does for it."""

_INSTRUCTION = re.compile(r"^Instruction: (.*)$", re.MULTILINE)
_FREE = re.compile(r"^Free characters: (.*)$", re.MULTILINE)


def directed(body: dict[str, Any]) -> str:
    """The reply to one planner request (the fake server's ``responder``)."""
    asked = [m["content"] for m in body["messages"] if "Free characters: " in m["content"]][-1]
    said = _INSTRUCTION.findall(asked)
    free = [n.strip() for n in _FREE.findall(asked)[-1].split(",")]
    if said and "toast" in said[-1] and "Max" in free:
        return interact_program("Max", *TOASTER)
    return first_free(body)

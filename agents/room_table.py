"""The label-to-room table (``prompts/describer/rooms.toml``): which kinds of room or area an
object label plausibly stands in, and what people do with it.

The table is data the project keeps (general household, office and restaurant knowledge);
this module only reads it and looks things up:

- :meth:`RoomTable.label` finds a scene label's entry: the label itself, an alias ("sofa" for
  ``couch``), the singular ("bottles"), then the longest run of its words that is known
  ("kitchen_sink" -> ``sink``, "office_desk" -> ``desk``). An unknown label is None: it says
  nothing about the room (nor does a label whose rooms are ``"*"``, e.g. a potted plant).
- :meth:`RoomTable.kind_of` maps a free area name to a kind: the kind itself, a synonym
  ("TV corner" -> living room), else the longest kind name or synonym inside it as whole words
  ("cozy living room" -> living room); None when nothing matches.

Guarantee: loading validates the table (every room a kind or ``"*"``, every alias unique and
never another label), so a lookup never meets a dangling name.
"""

from __future__ import annotations

import functools
import re
import tomllib

from pydantic import BaseModel, ConfigDict, Field, model_validator

from storyteller.agents.prompt_templates import PromptLibrary, package_prompts

ROOMS_FILE = "describer/rooms.toml"
ANYWHERE = "*"


class RoomKind(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    synonyms: tuple[str, ...] = ()
    functions: tuple[str, ...] = ()


class LabelRooms(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    rooms: tuple[str, ...] = Field(min_length=1)
    functions: tuple[str, ...] = Field(min_length=1)
    aliases: tuple[str, ...] = ()

    @property
    def anywhere(self) -> bool:
        """Stands in any room (a plant, a lamp): says nothing about the area."""
        return ANYWHERE in self.rooms


class RoomTable(BaseModel):
    """Kinds (in the describer's order) and labels, as ``rooms.toml`` states them."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    kinds: dict[str, RoomKind]
    labels: dict[str, LabelRooms]

    @model_validator(mode="after")
    def _consistent(self) -> RoomTable:
        seen: dict[str, str] = {}
        for label, entry in self.labels.items():
            unknown = [r for r in entry.rooms if r != ANYWHERE and r not in self.kinds]
            if unknown:
                raise ValueError(f"labels.{label}.rooms: {unknown} are not kinds")
            for alias in entry.aliases:
                if alias in self.labels or alias in seen:
                    raise ValueError(f"labels.{label}.aliases: {alias!r} is already {seen.get(alias, 'a label')}")
                seen[alias] = label
        return self

    @functools.cached_property
    def _alias_of(self) -> dict[str, str]:
        return {a: label for label, e in self.labels.items() for a in e.aliases}

    @functools.cached_property
    def _kind_names(self) -> list[tuple[str, str]]:
        """(normalised name or synonym, kind), longest first."""
        pairs = [(_name_key(k), k) for k in self.kinds]
        pairs += [(_name_key(s), k) for k, e in self.kinds.items() for s in e.synonyms]
        return sorted(pairs, key=lambda p: -len(p[0]))

    def _exact(self, key: str) -> str | None:
        if key in self.labels:
            return key
        if key in self._alias_of:
            return self._alias_of[key]
        for singular in (key[:-2], key[:-1]) if key.endswith("s") else ():
            if singular in self.labels or singular in self._alias_of:
                return self._exact(singular)
        return None

    def canonical(self, label: str) -> str | None:
        """The table's label for a scene label (see the module docstring), or None."""
        words = [w for w in re.split(r"[^a-z]+", label.lower()) if w]
        if not words:
            return None
        for size in range(len(words), 0, -1):  # the longest known run of words, the last run first
            for start in range(len(words) - size, -1, -1):
                found = self._exact("_".join(words[start : start + size]))
                if found is not None:
                    return found
        return None

    def label(self, label: str) -> LabelRooms | None:
        found = self.canonical(label)
        return None if found is None else self.labels[found]

    def kind_of(self, name: str) -> str | None:
        """The kind a free area name means, or None (see the module docstring)."""
        key = _name_key(name)
        for known, kind in self._kind_names:
            if key == known:
                return kind
        padded = f" {key} "
        for known, kind in self._kind_names:
            if f" {known} " in padded:
                return kind
        return None


def _name_key(name: str) -> str:
    return " ".join(re.split(r"[^a-z0-9']+", name.lower().replace("_", " "))).strip()


def parse_room_table(text: str) -> RoomTable:
    """The table from the text of ``rooms.toml`` (ValueError naming the field when it is wrong)."""
    return RoomTable.model_validate(tomllib.loads(text))


@functools.lru_cache(maxsize=4)
def _cached(text: str) -> RoomTable:
    return parse_room_table(text)


def room_table(prompts: PromptLibrary | None = None) -> RoomTable:
    """The table of ``prompts`` (default: the installed ``prompts`` package), parsed once per text."""
    return _cached((prompts or package_prompts()).text(ROOMS_FILE))

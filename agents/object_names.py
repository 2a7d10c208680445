"""Everyday English names of the kinds of object scenes hold, read as the scene's labels.

A person writing an instruction says "the water cooler", "the bookcase", "the sofa" or "the
swivel chair"; the scene's labels are ``water_dispenser``, ``bookshelf``, ``couch`` and
``office_chair``. :data:`EVERYDAY_NAMES` lists, per object label, the names people commonly
use for that kind of thing (written per label from general English usage, the way a
thesaurus lists them, for the labels of the bundled scenes and other common furniture and
appliances; no entry comes from a benchmark case's wording). :func:`read_as_labels` rewrites
a text's everyday names into the label's own words before the shortlists
(:mod:`storyteller.agents.shortlist`) and the relation reader (:mod:`storyteller.agents.relation_words`) read it.

A name is only rewritten when no label of the scene is that name itself: in a scene that has
a ``bar`` label, "the bar" stays the bar. Pure: no LLM, no I/O.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable

EVERYDAY_NAMES: dict[str, tuple[str, ...]] = {
    "armchair": ("easy chair", "recliner", "lounge chair", "wing chair", "wingback chair", "club chair", "arm chair"),
    "bar_counter": ("bar", "bar top", "bartop", "counter of the bar", "drinks counter", "serving counter"),
    "bed": ("bunk", "cot", "mattress"),
    "bench": ("wooden seat", "park bench", "long seat"),
    "bookshelf": ("bookcase", "book case", "book shelf", "book shelves", "bookshelves", "shelf of books",
                  "shelves of books", "shelf full of books", "shelves full of books", "book rack", "shelving",
                  "shelf", "shelves"),
    "cabinet": ("cupboard", "sideboard", "dresser", "chest of drawers", "filing cabinet", "storage cabinet",
                "credenza", "locker"),
    "cash_register": ("cash till", "checkout counter", "checkout desk", "cash desk", "cash box", "point of sale",
                      "cashier desk", "cashier"),
    "chair": ("side chair",),
    "coffee_maker": ("coffee machine", "espresso machine", "coffeemaker", "coffee pot", "coffee brewer",
                     "percolator", "coffee station"),
    "couch": ("sofa", "settee", "loveseat", "love seat", "divan", "chesterfield", "sectional"),
    "desk": ("workstation", "work station", "writing desk", "work desk", "computer desk", "bureau", "workspace"),
    "dishwasher": ("dish washer", "dishwashing machine", "dish machine"),
    "dvd_player": ("disc player", "blu ray player", "bluray player", "video player", "dvd machine"),
    "floor_lamp": ("standing lamp", "standard lamp", "lamp stand", "reading lamp", "tall lamp"),
    "fridge": ("refrigerator", "icebox", "ice box", "fridge freezer", "cooler"),
    "laptop": ("laptop computer", "notebook computer", "notebook pc", "portable computer"),
    "loudspeaker": ("speaker", "speakers", "loud speaker", "sound system", "stereo", "hifi", "hi fi", "speaker box"),
    "microwave": ("microwave oven", "micro wave"),
    "monitor": ("computer screen", "computer monitor", "display", "desktop screen", "pc screen"),
    "office_chair": ("desk chair", "swivel chair", "computer chair", "task chair", "rolling chair"),
    "potted_plant": ("houseplant", "house plant", "pot plant", "flowerpot", "flower pot", "plant pot", "planter",
                     "fern", "ficus", "greenery"),
    "reception_desk": ("front desk", "reception", "reception counter", "check in desk", "welcome desk",
                       "information desk", "front counter"),
    "record_player": ("turntable", "gramophone", "phonograph", "vinyl player", "record deck", "record machine"),
    "sink": ("basin", "washbasin", "wash basin", "washbowl"),
    "stool": ("bar stool", "barstool", "high stool", "tall stool"),
    "stove": ("cooker", "hob", "cooktop", "cooking range"),
    "toaster": ("bread toaster", "toaster oven"),
    "tv": ("television", "telly", "tv set", "television set", "flat screen", "flatscreen", "telescreen"),
    "tv_stand": ("tv cabinet", "tv unit", "tv table", "media console", "media unit", "entertainment center",
                 "entertainment centre", "television stand", "television cabinet"),
    "water_dispenser": ("water cooler", "water fountain", "drinking fountain", "water machine", "water station",
                        "water tank", "water jug", "water point"),
    "white_board": ("whiteboard", "dry erase board", "dry wipe board", "marker board", "wipe board"),
    "wine_rack": ("wine shelf", "wine shelves", "wine rack shelf", "bottle rack", "wine display", "wine stand",
                  "rack of wine", "rack of bottles"),
}
"""Per object label, everyday names of that kind of thing (lower case, words separated by one
space; a plural "s" is read too)."""


def _words_of(label: str) -> str:
    return label.replace("_", " ")


_WORD = re.compile(r"[a-z0-9]+")


@functools.lru_cache(maxsize=64)
def _names(labels: tuple[str, ...]) -> tuple[tuple[tuple[str, ...], str | None], ...]:
    """The (name words, label words) of a scene with ``labels``: longest names first, a name
    that is itself one of the scene's labels left out, only names of labels the scene has, and
    each label's own words first among names as long (None: kept as written; "bar counter"
    stays, though "bar" is a name of it)."""
    own = {_words_of(label) for label in labels}
    pairs: list[tuple[str, str | None]] = [(words, None) for words in own]
    pairs += [
        (name, _words_of(label))
        for label, names in EVERYDAY_NAMES.items() if label in labels
        for name in names if name not in own
    ]
    pairs.sort(key=lambda p: -len(p[0].split()))
    return tuple((tuple(name.split()), words) for name, words in pairs)


def _is(word: str, wanted: str, last: bool) -> bool:
    return word == wanted or (last and word in (wanted + "s", wanted + "es"))


def read_as_labels(text: str, labels: Iterable[str]) -> str:
    """``text`` (lower case) with every everyday name of a label the scene has written as that
    label's words ("the water cooler" -> "the water dispenser"). Names are matched longest
    first (a plural "s" on the last word read too); a matched stretch is not read again."""
    words = list(_WORD.finditer(text))
    names = _names(tuple(sorted(set(labels))))
    out, at, i = [], 0, 0
    while i < len(words):
        for name, label_words in names:
            n = len(name)
            if i + n <= len(words) and all(
                _is(words[i + k].group(), name[k], k == n - 1) for k in range(n)
            ):
                if label_words is not None:
                    out += [text[at : words[i].start()], label_words]
                    at = words[i + n - 1].end()
                i += n
                break
        else:
            i += 1
    return "".join([*out, text[at:]])

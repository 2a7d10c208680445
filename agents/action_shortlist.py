"""Which action labels an event is about, ranked from its words.

A 0.5B model choosing among 25-40 action labels picks one whose name shares a word with the
event (``listen_to_music`` for "put some music on") or the one it just used, about as often as
the right one. The event's words usually say which label fits: a verb (``drinks``, ``dances``,
``pays``), an object with a verb (``switch on the TV``, ``open the fridge``), or a thing only
one action uses (``the bill``, ``the menu``, ``a desktop monitor``). :func:`rank_action_labels`
scores every offered label against the text with a small lexicon of general English cue
phrases per label (:data:`CUES`), plus the object the label names when the text names that
object (``use_toaster`` and "the toaster"), with the direction of switch-like labels taken
from the text (``on`` / ``off``, ``open`` / ``close``); :func:`action_shortlist` keeps the labels
close to the best. The event parser's grammar then offers only those (``storyteller.agents.program_grammar``)
and the prompt names the best as the suggestion.

The lexicon is written for the product's action labels (``storyteller.sim.motion.action_labels``) from
everyday wording, not from any benchmark case. A label absent from :data:`CUES` is still ranked
by the words of its own name. Pure: no LLM, no I/O.
"""

from __future__ import annotations

import functools
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from storyteller.agents.english_words import verb_lemmas
from storyteller.agents.shortlist import SYNONYMS, mentioned_labels

_TOKEN = re.compile(r"[a-z0-9]+|[,.;:!?]")
_WORD = re.compile(r"[A-Za-z]+")
_SYNONYMS = {
    **SYNONYMS,  # the object synonyms the object shortlist reads too
    "whiteboard": "white board", "cellphone": "phone", "mobile": "phone", "pc": "computer", "cupboard": "cabinet",
}
_IGNORED_LABEL_WORDS = frozenset({"on", "off", "to", "out", "the", "use", "take", "turn", "open", "close"})

BEVERAGES = (
    "water", "lemonade", "juice", "soda", "cola", "coke", "pop", "milk", "milkshake", "smoothie", "tea", "coffee",
    "espresso", "latte", "cappuccino", "mocha", "cocoa", "hot chocolate", "beer", "lager", "ale", "cider", "wine",
    "champagne", "prosecco", "cocktail", "mocktail", "whisky", "whiskey", "vodka", "gin", "rum", "brandy", "spritz",
    "iced tea", "kombucha", "soft drink", "beverage", "refreshment", "pint", "glass of", "cup of", "mug of",
    "bottle of", "can of",
)
"""Things people drink (general English): a text that has one and no verb of its own reads as
drinking ("to have a cold lemonade")."""
FOODS = (
    "food", "meal", "snack", "sandwich", "salad", "soup", "pizza", "pasta", "noodle", "rice", "burger", "fries",
    "chips", "steak", "chicken", "fish", "sushi", "curry", "stew", "omelette", "egg", "bread", "toast", "bagel",
    "croissant", "muffin", "cake", "cookie", "biscuit", "pie", "pastry", "donut", "doughnut", "cereal", "porridge",
    "oatmeal", "yogurt", "yoghurt", "fruit", "apple", "banana", "orange", "grapes", "pear", "cheese", "crackers",
    "nuts", "popcorn", "chocolate bar", "ice cream", "dessert", "pudding", "leftovers", "taco", "burrito", "wrap",
    "dumpling", "breakfast", "lunch", "dinner", "supper", "brunch", "bite to eat",
)
"""Things people eat (general English), read as eating in the same way."""


def _with_things(cues: tuple[tuple[str, int], ...], things: tuple[str, ...], weight: int) -> tuple[tuple[str, int], ...]:
    """``cues`` plus each of ``things`` at ``weight`` (a cue the label already has at a lower
    weight is raised to it)."""
    raised = tuple((c, max(w, weight) if c in things else w) for c, w in cues)
    have = {c for c, _ in cues}
    return raised + tuple((t, weight) for t in things if t not in have)


CUES: dict[str, tuple[tuple[str, int], ...]] = {
    "idle": (("wait", 2), ("rest", 2), ("relax", 2), ("pause", 2), ("nothing", 1), ("stand still", 3), ("sit still", 3),
             ("idle", 3), ("stay", 1), ("linger", 2), ("daydream", 2), ("think", 1)),
    "chat": (("chat", 3), ("talk", 3), ("conversation", 3), ("gossip", 3), ("speak", 2), ("joke", 2), ("catch up with", 2),
             ("tell", 1), ("small talk", 3), ("socialis", 2)),
    "discuss": (("discuss", 3), ("debate", 3), ("brainstorm", 3), ("argue", 2), ("go over", 2), ("review", 2), ("plan", 1),
                ("compare notes", 3)),
    "attend_meeting": (("meeting", 3), ("attend", 2), ("presentation", 2), ("stand up meeting", 3), ("conference", 2),
                       ("briefing", 2)),
    "handshake": (("shake hand", 4), ("handshake", 4), ("shakes hand", 4), ("introduce", 1), ("deal", 1)),
    "hug": (("hug", 4), ("embrace", 4), ("cuddle", 3)),
    "dance": (("danc", 4), ("waltz", 3), ("groove", 2), ("boogie", 3), ("tango", 3)),
    "drink": (("drink", 3), ("sip", 3), ("gulp", 3), ("slurp", 3), ("swig", 3), ("quaff", 3), ("thirst", 1),
              ("coffee", 1), ("tea", 1), ("juice", 1), ("beer", 1), ("wine", 1),
              ("mug", 1), ("glass of", 1), ("cup of", 1), ("cocktail", 1), ("soda", 1)),
    "eat": (("eat", 3), ("nibble", 3), ("munch", 3), ("chew", 2), ("devour", 3), ("gobble", 3), ("feast", 2),
            ("tuck in", 3), ("meal", 2), ("breakfast", 2), ("lunch", 2), ("dinner", 2), ("snack", 2), ("dine", 2),
            ("supper", 2), ("bite", 1), ("sandwich", 1), ("toast", 1), ("food", 1), ("dessert", 2),
            ("bowl", 1), ("cereal", 2), ("fork", 1), ("spoon", 1)),
    "use_smartphone": (("phone", 3), ("text", 2), ("scroll", 2), ("message", 2), ("call", 1), ("selfie", 3),
                       ("social media", 3)),
    "read_book": (("read", 3), ("book", 2), ("novel", 3), ("magazine", 3), ("newspaper", 3), ("chapter", 2),
                  ("page", 1), ("story", 1)),
    "use_laptop": (("laptop", 4), ("type", 2), ("notes", 1), ("notebook", 1)),
    "work_on_computer": (("computer", 4), ("monitor", 3), ("desktop", 3), ("email", 2), ("mail", 1), ("spreadsheet", 3),
                         ("code", 2), ("program", 1), ("keyboard", 2), ("screen", 1), ("work", 1)),
    "watch_tv": (("watch", 3), ("tv", 2), ("show", 2), ("film", 2), ("movie", 2), ("news", 2), ("series", 2),
                 ("match", 1), ("episode", 2), ("cartoon", 2)),
    "listen_to_music": (("listen", 3), ("music", 2), ("song", 2), ("tune", 1), ("album", 2), ("record", 1),
                        ("melody", 2), ("radio", 2), ("playlist", 2)),
    "wave": (("wave", 4), ("greet", 2), ("hello", 2), ("goodbye", 2), ("bye", 2), ("hi to", 2), ("signal", 1)),
    "turn_on_tv": (("switch on the tv", 4), ("turn on the tv", 4), ("tv on", 3), ("switch on the screen", 4),
                   ("turn on the screen", 4), ("screen on", 3)),
    "turn_off_tv": (("switch off the tv", 4), ("turn off the tv", 4), ("tv off", 3), ("switch off the screen", 4),
                    ("turn off the screen", 4), ("screen off", 3)),
    "turn_on_record_player": (("put on a record", 4), ("put some music on", 4), ("put music on", 4), ("put on some music", 4),
                              ("play a record", 4), ("start the music", 3), ("music on", 3), ("vinyl", 3),
                              ("record on", 4), ("spin a record", 4), ("lp", 3), ("needle on", 3)),
    "turn_off_record_player": (("stop the music", 4), ("music off", 3), ("turn the music off", 4),
                               ("stop the record", 4), ("record off", 3), ("needle off", 3), ("lift the needle", 4)),
    "open_fridge": (("open the fridge", 4), ("look in the fridge", 3), ("check the fridge", 3)),
    "close_fridge": (("close the fridge", 4), ("shut the fridge", 4)),
    "open_cabinet": (("open the cabinet", 4), ("look in the cabinet", 3)),
    "close_cabinet": (("close the cabinet", 4), ("shut the cabinet", 4)),
    "use_coffee_maker": (("make coffee", 4), ("makes coffee", 4), ("making coffee", 4), ("make cup", 3), ("brew", 3),
                         ("coffee is made", 4), ("coffee gets made", 4), ("espresso", 3),
                         ("cappuccino", 3), ("latte", 2), ("coffee machine", 4)),
    "use_toaster": (("toast", 3), ("toaster", 4)),
    "use_microwave": (("microwave", 4), ("heat up", 3), ("reheat", 3), ("warm up", 3), ("heat", 2), ("warm", 1),
                      ("leftover", 2), ("popcorn", 2)),
    "use_dishwasher": (("dishwasher", 4), ("load the dish", 4), ("dishes", 2), ("wash up", 3), ("dirty", 2),
                       ("unload", 2)),
    "use_water_dispenser": (("water dispenser", 4), ("water cooler", 4), ("fill", 3), ("refill", 3), ("water", 2),
                            ("top up", 2)),
    "take_out_drink": (("take out a drink", 4), ("take a drink out", 4), ("grab a drink", 4), ("get a drink", 4),
                       ("take out", 1), ("grab", 1), ("fetch", 1), ("can of", 2), ("bottle", 2), ("soda", 2)),
    "take_out_document": (("document", 4), ("file", 3), ("folder", 3), ("paper", 2), ("report", 2), ("contract", 2),
                          ("printout", 3), ("form", 1)),
    "take_out_book": (("take out a book", 4), ("take a book", 4), ("pick a book", 4), ("get a book", 4),
                      ("borrow", 3), ("from the shelf", 3), ("bookshelf", 2), ("bookcase", 2)),
    "clean_white_board": (("clean the white board", 5), ("wipe the white board", 5), ("erase", 4), ("wipe", 2),
                          ("clean", 2), ("rub out", 3)),
    "write_on_white_board": (("write on the white board", 5), ("write", 3), ("draw", 3), ("sketch", 3),
                             ("white board", 2), ("diagram", 2), ("jot", 2)),
    "clean_table": (("clean the table", 5), ("wipe the table", 5), ("wipe", 2), ("clean", 2), ("tidy", 2),
                    ("crumb", 2), ("clear the table", 4)),
    "deliver_menu": (("menu", 4), ("bring the menu", 5), ("hand out", 2)),
    "serve_food": (("serve", 2), ("bring", 1), ("dish", 2), ("plate", 1), ("food", 1), ("meal", 1), ("course", 2),
                   ("carry", 1), ("deliver", 1), ("hand over", 2)),
    "serve_drink": (("serve", 2), ("bring", 1), ("drink", 1), ("carry", 1), ("deliver", 1), ("tray", 1), ("hand over", 2)),
    "take_order": (("take the order", 5), ("take order", 5), ("takes the order", 5), ("taking the order", 5),
                   ("note down", 3), ("write down", 3), ("jot down", 3), ("what they want", 3),
                   ("what they would like", 3), ("ask what", 2), ("order", 1)),
    "order_food": (("order food", 5), ("order a meal", 5), ("order", 2), ("ask for", 2), ("food", 1), ("meal", 1), ("dish", 1),
                   ("pizza", 1), ("salad", 1), ("soup", 1), ("burger", 1), ("pasta", 1)),
    "order_drink": (("order a drink", 5), ("order", 2), ("ask for", 2), ("drink", 1), ("coffee", 1), ("beer", 1), ("wine", 1),
                    ("juice", 1), ("tea", 1)),
    "pay_bill": (("pay", 4), ("bill", 4), ("check please", 4), ("cheque", 3), ("settle up", 3), ("the tab", 3),
                 ("receipt", 2)),
}
"""Cue phrases per label with a weight. A cue word matches a text word that starts with it
(``drink`` matches "drinks", "drinking"), so cues are stems; phrases match consecutive words."""
CUES["drink"] = _with_things(CUES["drink"], BEVERAGES, 2)
CUES["eat"] = _with_things(CUES["eat"], FOODS, 2)
CUES["order_drink"] = _with_things(CUES["order_drink"], BEVERAGES, 1)
CUES["order_food"] = _with_things(CUES["order_food"], FOODS, 1)
CUES["serve_drink"] = _with_things(CUES["serve_drink"], BEVERAGES, 1)
CUES["serve_food"] = _with_things(CUES["serve_food"], FOODS, 1)

SWITCHES = {
    "turn_on_": ("on", "start", "power"),
    "turn_off_": ("off", "stop", "shut", "silence", "mute"),
    "open_": ("open",),
    "close_": ("close", "shut"),
    "take_out_": ("take", "grab", "fetch", "get", "pick", "pull", "remove"),
}
"""Label prefixes whose direction the text must give, and the words that give it."""
OPPOSITES = {"turn_on_": "turn_off_", "turn_off_": "turn_on_", "open_": "close_", "close_": "open_"}
"""Switch prefixes with an opposite: when a label's opposite is not offered (the story holds the
state it would set, :mod:`storyteller.agents.object_states`), only one direction is left and the text need
not give it ("wanting some peace, Jo sees to the TV" with the TV on)."""

KEEP_RATIO = 0.5
"""A label stays on the shortlist when its score is at least this share of the best score."""
MAX_SHORTLIST = 4


@dataclass(frozen=True)
class RankedLabel:
    label: str
    score: int


_DETERMINERS = frozenset({"their", "his", "her", "its", "our", "my", "your"})
"""Possessives read as "the", so a cue phrase names its thing whoever owns it ("takes their order")."""


_PARTICLES = frozenset({"for", "over", "out", "off", "on", "up", "down", "back", "to", "away", "in"})
"""Words after which *her* is a person, not a possessive ("asks her for", "hands her over")."""


def _tokens(text: str) -> list[str]:
    out: list[str] = []
    words = _TOKEN.findall(text.lower().replace("_", " ").replace("-", " "))
    for k, w in enumerate(words):
        person = w == "her" and k + 1 < len(words) and words[k + 1] in _PARTICLES
        out.extend(("her",) if person else ("the",) if w in _DETERMINERS else _SYNONYMS.get(w, w).split())
    return out


PERSON_NOUNS = frozenset({
    "waiter", "waiters", "waitress", "waitresses", "server", "servers", "reader", "readers", "drinker", "eater",
    "dancer", "dancers", "worker", "workers", "writer", "cleaner", "cleaners", "caller", "player", "players",
    "viewer", "viewers", "watcher", "listener", "speaker", "speakers", "talker", "chatter", "cook", "cooks",
})
"""Nouns for people made from verbs: "the waiter" is no one waiting, "the cleaner" no cleaning."""


def _word_matches(cue: str, word: str) -> bool:
    if word == cue:
        return True
    if not word[0].isalnum() or word in PERSON_NOUNS:
        return False
    if cue in verb_lemmas(word):  # a form the endings below miss: "carries" is carry, "ate" is eat
        return True
    if len(cue) <= 3:  # short stems only inflect: "sip" -> "sipping", not "tab" -> "table"
        return word in {cue + "s", cue + "es", cue + "ed", cue + "ing", cue + cue[-1] + "ing", cue + cue[-1] + "ed"}
    return word.startswith(cue) and len(word) - len(cue) <= 3


_FILLERS = frozenset({"a", "an", "some", "himself", "herself", "themselves", "myself", "yourself", "ourselves",
                      "him", "her", "them", "me", "us", "it"})
"""Words a cue phrase may skip between its own words: "makes himself a coffee" says "make coffee",
"asks her for a gin" says "ask for", "hands it over" says "hand over" (object pronouns)."""


def _phrase_at(tokens: Sequence[str], phrase: Sequence[str]) -> list[int]:
    """Where ``phrase`` starts in ``tokens``: its words in order, consecutive but for fillers."""
    starts = []
    for i in range(len(tokens)):
        j = i
        for k, p in enumerate(phrase):
            while k > 0 and j < len(tokens) and tokens[j] in _FILLERS and not _word_matches(p, tokens[j]):
                j += 1
            if j >= len(tokens) or not _word_matches(p, tokens[j]):
                break
            j += 1
        else:
            starts.append(i)
    return starts


def _without_proximity(tokens: list[str]) -> list[str]:
    """Read "close to" / "close by" / "next to" as "near": places, not the close / shut action."""
    out: list[str] = []
    skip = False
    for i, t in enumerate(tokens):
        if skip:
            skip = False
            continue
        if t in ("close", "next") and i + 1 < len(tokens) and tokens[i + 1] in {"to", "by"}:
            out.append("near")
            skip = True
            continue
        out.append(t)
    return out


_SWITCH_VERBS = ("switch", "turn", "put", "power", "flip", "click", "shut")


_LANDMARK_HEADS = (
    "near", "nearest", "closest", "beside", "facing", "opposite", "behind", "by", "next", "across", "where", "between",
    "left", "right", "toward", "towards", "overlooking", "farthest", "furthest", "farther", "further", "far",
    "distant", "away", "avoiding", "avoids", "avoid", "nearby", "adjacent", "alongside", "halfway", "midway", "faces",
)
_LANDMARK_ENDS = frozenset({"and", "then", "to", "while", "so", "but", "or", "after", "before", "where", "which", "who"})
LANDMARK_SPAN = 4
"""Words after a place word ("nearest the water dispenser") name a landmark, not what the
character does: cues there do not count."""


_ROOMS = frozenset({
    "room", "kitchen", "kitchenette", "office", "area", "corner", "lounge", "hall", "hallway", "lobby", "corridor",
    "bedroom", "bathroom", "studio", "cafeteria", "canteen", "pantry",
})
"""Words ending a place name after "in" ("in the meeting room"): the words before them name a place."""


def _landmark_mask(tokens: Sequence[str]) -> list[bool]:
    mask = [False] * len(tokens)
    for i, t in enumerate(tokens):
        if t == "in":  # "in the meeting room": a place, not what is done there
            end = next((k for k in range(i + 1, min(len(tokens), i + 1 + LANDMARK_SPAN)) if tokens[k] in _ROOMS), None)
            for k in range(i + 1, end + 1 if end is not None else i + 1):
                mask[k] = True
        if t in _LANDMARK_HEADS or (t == "front" and i > 0 and tokens[i - 1] == "in"):
            pair = t == "between"  # "between the table and the couch": one "and" belongs to it
            for k in range(i + 1, min(len(tokens), i + 1 + LANDMARK_SPAN * (2 if pair else 1))):
                if pair and tokens[k] == "and":
                    pair = False
                elif tokens[k] in _LANDMARK_ENDS or not tokens[k][0].isalnum():
                    break
                mask[k] = True
    return mask


def _direction(tokens: Sequence[str], prefix: str) -> bool:
    """Whether the text gives the label's direction: "on" / "off" within three words after a
    switching verb ("switch the TV on"; "sits on the couch" is no direction), or a verb of it
    ("starts", "opens", "shuts")."""
    words = SWITCHES[prefix]
    for i, t in enumerate(tokens):
        if t in ("on", "off"):
            if t in words and any(_word_matches(v, w) for v in _SWITCH_VERBS for w in tokens[max(0, i - 4) : i]):
                return True
        elif any(_word_matches(w, t) for w in words if w not in ("on", "off")):
            return True
    return False


@functools.cache
def _cue_tokens(phrase: str) -> tuple[str, ...]:
    return tuple(_tokens(phrase))


def label_score(
    label: str, tokens: Sequence[str], named_objects: Iterable[str], landmark: Sequence[bool] | None = None,
    one_way: bool = False, fetch_opens: bool = False,
) -> int:
    """Score of one label for the event's tokens; ``named_objects`` are the object labels the
    text names (``coffee_maker``); ``landmark``: :func:`_landmark_mask` of the tokens (computed
    when not given); ``one_way``: the label's opposite switch is not offered (:data:`OPPOSITES`),
    so a text without a direction is not marked down; ``fetch_opens``: no ``take_out_`` label is
    offered, so taking something out of a thing the text names ("gets the milk from the fridge")
    is opening it: a fetching verb gives an ``open_`` label its direction."""
    score = 0
    landmark = _landmark_mask(tokens) if landmark is None else landmark
    for phrase, weight in CUES.get(label, ()):
        if any(not landmark[i] for i in _phrase_at(tokens, _cue_tokens(phrase))):
            score += weight
    words = [w for w in label.split("_") if w not in _IGNORED_LABEL_WORDS]
    if label not in CUES:
        score += 2 * sum(1 for w in words if any(_word_matches(w, t) for t in tokens))
    prefix = next((p for p in SWITCHES if label.startswith(p)), None)
    target = label.removeprefix(prefix) if prefix else label.removeprefix("use_")
    if any(obj == target or obj.endswith("_" + target) for obj in named_objects):
        score += 3
    if prefix is not None and score and (
        _direction(tokens, prefix) or (prefix == "open_" and fetch_opens and _direction(tokens, "take_out_"))
    ):
        score += 2
    elif prefix is not None and not one_way:
        score //= 2
    return score


CONSUMING = frozenset({"eat", "drink"})
"""Labels of taking food or drink oneself: not what a character does who carries it to others."""
_HANDING_VERBS = ("bring", "carry", "deliver", "hand", "pass", "fetch", "serve")
_OTHERS = frozenset({"them", "their", "theirs", "guest", "guests", "customer", "customers", "diner", "diners"})


def _handed_to_others(text: str) -> bool:
    """Whether ``text`` has its subject hand something on to other people ("carries their dinner
    over", "brings them drinks", "brings it to Ben"): a verb of bringing and a word for the
    others or a name after "to" / "for". "Her" and "his" do not count: they may be the
    subject's own ("brings her coffee to the couch")."""
    found = _WORD.findall(text)
    words = [w.lower() for w in found]
    # "to Ben", "for Ava": a capitalised word after "to" / "for" past the first word is a person
    named = any(words[k - 1] in ("to", "for") and found[k][:1].isupper() for k in range(2, len(found)))
    return (named or bool(_OTHERS & set(words))) and any(_word_matches(v, w) for v in _HANDING_VERBS for w in words)


_ASIDE_OPENERS = frozenset({"who", "whose", "which"})
_TIME_OPENERS = frozenset({"once", "when", "whenever", "until", "till"})
_CLAUSE_ENDS = frozenset({",", ".", ";", "!", "?"})


def main_clause(tokens: Sequence[str], asides: bool = True) -> list[str]:
    """``tokens`` without the clauses that say who someone is or when something happens, not
    what is done: an aside after a comma that opens with *who* / *which*, up to the next comma
    or the end ("Cleo, who waits tables here, jots down ...", "brings it to Ben, who waits on
    the bench with his phone") and a clause of time ("... once the film is over", "When the
    film ends, ..."), up to the next punctuation. ``asides=False`` keeps the asides."""
    out: list[str] = []
    i = 0
    while i < len(tokens):
        t = tokens[i]
        aside = asides and t == "," and i + 1 < len(tokens) and tokens[i + 1] in _ASIDE_OPENERS
        timing = t in _TIME_OPENERS or (t == "as" and tokens[i + 1 : i + 3] == ["soon", "as"])
        if aside or timing:
            end = next((k for k in range(i + 1, len(tokens)) if tokens[k] in _CLAUSE_ENDS), len(tokens))
            i = end + 1 if (aside or not out) and end < len(tokens) else end
            continue
        out.append(t)
        i += 1
    return out


def _scores(text: str, labels: Sequence[str], object_labels: Sequence[str]) -> list[int]:
    all_tokens = _without_proximity(_tokens(text))
    scores = _clause_scores(text, main_clause(all_tokens), labels, object_labels)
    if any(scores):
        return scores
    # the aside says what is done when the rest names no action ("a chair will do for Zainab,
    # who wants to sip a lemonade")
    return _clause_scores(text, main_clause(all_tokens, asides=False), labels, object_labels)


def _clause_scores(text: str, tokens: list[str], labels: Sequence[str], object_labels: Sequence[str]) -> list[int]:
    landmark = _landmark_mask(tokens)
    acted_on = " ".join(t for t, skip in zip(tokens, landmark, strict=True) if not skip)
    known = list(dict.fromkeys([*object_labels, *(label_objects(labels))]))
    # both readings: "a shelf of books" names the bookshelf and books
    named = list(dict.fromkeys([*mentioned_labels(acted_on, known), *mentioned_labels(acted_on, known, everyday=False)]))
    offered = set(labels)

    def one_way(label: str) -> bool:
        prefix = next((p for p in OPPOSITES if label.startswith(p)), None)
        return prefix is not None and OPPOSITES[prefix] + label.removeprefix(prefix) not in offered

    # taking something out of a thing is opening it unless an offered take_out_ label is about
    # that something ("gets the milk from the fridge" with only take_out_book offered opens it)
    fetch_opens = not any(
        label.startswith("take_out_") and label_score(label, tokens, named, landmark) > 0 for label in labels)
    handed_on = _handed_to_others(text)
    return [0 if handed_on and label in CONSUMING else label_score(label, tokens, named, landmark, one_way(label), fetch_opens)
            for label in labels]


def rank_action_labels(
    text: str, labels: Sequence[str], object_labels: Sequence[str] = (), context: str = ""
) -> list[RankedLabel]:
    """Every label with a positive score, best first; ties go to the label ``context`` (other
    words about the same event, e.g. the narrator's activity) scores higher, then ``labels``
    order ("serves it to him" is serve_food or serve_drink; "serve drink to him" decides)."""
    scores = _scores(text, labels, object_labels)
    second = _scores(context, labels, object_labels) if context.strip() else [0] * len(labels)
    order = sorted(range(len(labels)), key=lambda i: (-scores[i], -second[i], i))
    return [RankedLabel(labels[i], scores[i]) for i in order if scores[i] > 0]


def switch_directions(text: str) -> tuple[str, ...]:
    """The switch prefixes (``open_``, ``close_``, ``turn_on_``, ``turn_off_``) whose direction
    words ``text`` says ("pushes the door shut": ``close_`` and ``turn_off_``)."""
    tokens = _tokens(text)
    return tuple(p for p in OPPOSITES if any(_word_matches(w, t) for w in SWITCHES[p] for t in tokens))


def label_objects(labels: Sequence[str]) -> list[str]:
    """The objects labels name (``use_toaster`` -> ``toaster``), so the text's mention of one
    counts even when the scene's object labels were not given."""
    out = []
    for label in labels:
        prefix = next((p for p in SWITCHES if label.startswith(p)), None)
        if prefix:
            out.append(label.removeprefix(prefix))
        elif label.startswith("use_"):
            out.append(label.removeprefix("use_"))
    return out


def action_shortlist(
    text: str, labels: Sequence[str], object_labels: Sequence[str] = (), context: str = ""
) -> tuple[str, ...]:
    """The labels close to the best (at most :data:`MAX_SHORTLIST`), best first; empty when the
    text gives no evidence (the caller then offers every label)."""
    ranked = rank_action_labels(text, labels, object_labels, context)
    if not ranked:
        return ()
    best = ranked[0].score
    return tuple(r.label for r in ranked if r.score >= KEEP_RATIO * best)[:MAX_SHORTLIST]


_SIT_WORDS = ("sit", "seat", "chair", "stool", "couch", "armchair", "bench", "perch")
_STAND_WORDS = ("stand", "upright")
_RELATIVE = frozenset({"which", "whichever", "that", "where", "whose"})


_CLAIM_VERBS = ("grab", "get", "take", "find", "snag", "claim", "book")
"""Verbs of "grab a table" / "find a table" / "book a table": to sit at it (an idiom of eating out)."""


def _claims_a_table(said: Sequence[str]) -> bool:
    """Whether a claiming verb has "table" as its object: itself and at most two words between."""
    return any(t == "table" and any(_word_matches(v, w) for v in _CLAIM_VERBS for w in said[max(0, i - 3) : i])
               for i, t in enumerate(said))


def posture(text: str) -> str | None:
    """``"sit"`` when the event's words say the characters sit ("takes a seat", "seated",
    "on the couch", "grab the little table"), ``"stand"`` when they say they stand, None when they say neither or both.
    Words naming a landmark ("chats next to the couch") do not count."""
    tokens = _without_proximity(_tokens(text))
    landmark = _landmark_mask(tokens)
    said = [t for t, skip in zip(tokens, landmark, strict=True) if not skip]
    sit = any(_word_matches(w, t) for w in _SIT_WORDS for t in said) or _claims_a_table(said)
    stand = any(
        _word_matches(w, t) and not _RELATIVE & set(said[max(0, i - 4) : i])  # "the table which stands by"
        for i, t in enumerate(said) for w in _STAND_WORDS
    )
    if sit == stand:
        return None
    return "sit" if sit else "stand"


def suggested_action(text: str, labels: Sequence[str], object_labels: Sequence[str] = (), context: str = "") -> str:
    """The best label for the text, or ``idle`` (the first label when idle is not offered)."""
    ranked = rank_action_labels(text, labels, object_labels, context)
    if ranked:
        return ranked[0].label
    return "idle" if "idle" in labels or not labels else labels[0]

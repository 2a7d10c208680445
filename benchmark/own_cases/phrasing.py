"""The words our generated cases are written with: object nouns, activities, names, sentence shapes.

Everything here is general English written for the project (no text of any benchmark case):
nouns and synonyms per object label, activities per action label (infinitive phrases; the
third person is made by :func:`third_person`), and the sentence shapes each recipe of
:mod:`.generate` fills. A shape has an id (``<recipe>.<letter>``): the split of
:mod:`.split` puts every case of one shape on the same side, so the test set's sentences
are shapes the development set never shows.

Slots of a shape: ``{who}`` (the acting character), ``{act}`` / ``{act3}`` (the activity,
infinitive / third person), ``{seat}`` / ``{seats}`` (a seat noun, plural), ``{lm}`` / ``{lm2}``
(landmark nouns), ``{thing}`` (the object of a place), ``{side}`` / ``{other_side}`` (left,
right), ``{others}`` (characters already there, with ``{are}`` / ``{have}`` agreeing), ``{friend}`` (one of them), ``{table}``.
"""

from __future__ import annotations

NOUNS: dict[str, tuple[str, ...]] = {
    "fridge": ("fridge", "refrigerator"),
    "dishwasher": ("dishwasher",),
    "coffee_maker": ("coffee maker", "coffee machine"),
    "toaster": ("toaster",),
    "microwave": ("microwave", "microwave oven"),
    "couch": ("couch", "sofa"),
    "armchair": ("armchair", "easy chair"),
    "tv_stand": ("TV stand", "low television cabinet"),
    "tv": ("TV", "television"),
    "dvd_player": ("DVD player",),
    "bookshelf": ("bookcase", "bookshelf", "tall shelf of books"),
    "record_player": ("record player", "turntable"),
    "loudspeaker": ("loudspeaker", "speaker"),
    "potted_plant": ("potted plant", "houseplant"),
    "floor_lamp": ("floor lamp", "standing lamp"),
    "desk": ("desk", "writing desk"),
    "laptop": ("laptop",),
    "monitor": ("monitor",),
    "white_board": ("whiteboard", "white board"),
    "water_dispenser": ("water dispenser", "water cooler"),
    "bar_counter": ("bar counter", "bar"),
    "wine_rack": ("wine rack",),
    "reception_desk": ("reception desk", "front desk"),
    "cash_register": ("cash register", "till"),
    "bench": ("bench", "wooden bench"),
    "table": ("table",),
    "chair": ("chair",),
    "office_chair": ("office chair", "desk chair", "swivel chair"),
    "stool": ("stool", "bar stool"),
}
"""Nouns a label may be called by (the first is the plainest)."""

PLURALS: dict[str, tuple[str, ...]] = {
    "chair": ("chairs",),
    "office_chair": ("office chairs", "desk chairs", "swivel chairs"),
    "stool": ("stools", "bar stools"),
    "table": ("tables",),
    "desk": ("desks",),
    "loudspeaker": ("loudspeakers", "speakers"),
    "potted_plant": ("potted plants", "plants in pots"),
}

LANDMARK_EXCLUDED = frozenset({"table", "chair", "office_chair", "stool", "plate", "bottle", "book", "cabinet", "desk"})
"""Labels never used as a landmark: too generic or too small to steer by."""

DEVICE_USES: dict[str, tuple[tuple[str, tuple[str, ...]], ...]] = {
    "coffee_maker": (("use_coffee_maker", ("brew a fresh pot of coffee", "make a cappuccino with the {noun}",
                                           "get the {noun} going for a flat white")),),
    "toaster": (("use_toaster", ("toast two slices of rye bread", "make some toast for breakfast",
                                 "crisp up a bagel in the {noun}")),),
    "microwave": (("use_microwave", ("heat up last night's curry", "warm a mug of milk in the {noun}",
                                     "reheat a plate of noodles")),),
    "dishwasher": (("use_dishwasher", ("stack the dirty plates in the {noun}", "run the {noun} after dinner",
                                       "unload the clean glasses from the {noun}")),),
    "fridge": (("open_fridge", ("fetch a carton of juice from the {noun}", "look in the {noun} for some cheese",
                                "get a cold yoghurt out")),),
    "water_dispenser": (("use_water_dispenser", ("refill a bottle with chilled water",
                                                 "get a paper cup of water from the {noun}")),),
    "record_player": (("turn_on_record_player", ("put an old jazz album on the {noun}", "start a vinyl spinning")),),
    "tv": (("turn_on_tv", ("switch the {noun} on for the football scores", "power up the {noun}")),),
    "white_board": (("write_on_white_board", ("draw a timeline on the {noun}", "jot the week's goals on the {noun}")),
                    ("clean_white_board", ("wipe the old notes off the {noun}", "clean the {noun} before the next talk"))),
    "bookshelf": (("take_out_book", ("pull a binder off the {noun}", "fetch a reference manual from the {noun}")),),
    "cash_register": (("pay_bill", ("pay for the meal", "settle up for two coffees at the {noun}")),),
}
"""Standing uses of a device: label -> (action label, activities; ``{noun}`` is a noun of the device)."""

SEATED: dict[str, tuple[str, ...]] = {
    "read_book": ("read a detective novel", "get through a few chapters of a paperback", "leaf through a magazine"),
    "use_smartphone": ("scroll through the news on a phone", "answer some text messages", "phone a cousin abroad"),
    "drink": ("drink a mug of green tea", "sip some sparkling water", "have a cold lemonade"),
    "eat": ("eat a cheese sandwich", "have an apple and some crackers", "eat a bowl of salad"),
}
"""Seated activities that need no particular object (the seat is chosen by the relation)."""

STANDING: dict[str, tuple[str, ...]] = {
    "use_smartphone": ("check the weather on a phone", "read an email on a phone"),
    "drink": ("finish a bottle of water", "drink a quick espresso"),
    "listen_to_music": ("listen to the music", "enjoy the record that is playing"),
}
"""Standing activities (a place between two things)."""

SEATED_USES: dict[str, tuple[str, ...]] = {
    "use_laptop": ("type up meeting notes on the laptop", "edit a spreadsheet on a laptop", "browse holiday photos on the laptop"),
    "work_on_computer": ("answer emails on a desktop computer", "write some code on one of the desktop computers",
                         "update a spreadsheet at a desktop monitor"),
    "watch_tv": ("watch the evening news on TV", "watch a cooking show on the television", "catch a film on TV"),
    "eat": ("have dinner where the plates are already set", "eat at a table laid with plates",
            "have lunch at a place set with a plate"),
    "order_drink": ("order a glass of red wine at the bar", "ask for a beer at the bar", "order a lemonade at the bar"),
    "attend_meeting": ("take part in the team meeting at the conference table", "join the planning meeting at the big table"),
}
"""Seated uses whose activity already names what the seat is for."""

NAMES: tuple[str, ...] = (
    "Abebe", "Adaeze", "Agnes", "Ahmed", "Aino", "Alma", "Anders", "Anouk", "Arjun", "Astrid", "Bao", "Basil",
    "Beatriz", "Bilal", "Bjorn", "Camila", "Casper", "Chiara", "Chidi", "Clara", "Dalia", "Darius", "Dilnoza",
    "Duc", "Edda", "Efua", "Elias", "Emre", "Enzo", "Esra", "Ewa", "Fatou", "Femi", "Finn", "Gaspard", "Gita",
    "Goran", "Hakon", "Halima", "Hiro", "Ida", "Ilse", "Imani", "Irina", "Ismail", "Jalen", "Janek", "Jia",
    "Jonas", "Juno", "Kalani", "Karim", "Kasia", "Kwame", "Lale", "Lena", "Lior", "Luca", "Mads", "Malik",
    "Marisol", "Matteo", "Mihai", "Milan", "Nadia", "Naveen", "Nell", "Nils", "Noor", "Odette", "Olu", "Oskar",
    "Paloma", "Petra", "Priya", "Quinn", "Rafael", "Rania", "Reza", "Rohan", "Rosa", "Ruth", "Saoirse", "Selim",
    "Signe", "Soren", "Taini", "Tamar", "Teodor", "Tomas", "Uma", "Valeria", "Viktor", "Wanjiru", "Xiang",
    "Yasmin", "Yusra", "Zainab", "Zofia", "Zoltan",
)

# ----- sentence shapes per recipe (id -> shape) ---------------------------------------------------
SHAPES: dict[str, dict[str, str]] = {
    "oa.device": {
        "a": "{who} is about to {act}.",
        "b": "{who} gets up to {act}.",
        "c": "Next, {who} is going to {act}.",
        "d": "{who} has a spare moment and decides to {act}.",
        "e": "After a long morning, {who} goes off to {act}.",
    },
    "oa.seated_use": {
        "a": "{who} means to {act}.",
        "b": "{who} settles in to {act}.",
        "c": "For the next hour {who} plans to {act}.",
        "d": "{who} finds a suitable place to {act}.",
    },
    "rc.seat_near": {
        "a": "{who} sits on the {seat} closest to the {lm} to {act}.",
        "b": "Choosing the {seat} right next to the {lm}, {who} sits down to {act}.",
        "c": "{who} wants to {act} and takes the {seat} that is nearest the {lm}.",
        "d": "Of all the {seats}, {who} picks the one by the {lm} and sits to {act}.",
    },
    "rc.seat_far": {
        "a": "{who} sits on the {seat} farthest from the {lm} to {act}.",
        "b": "To keep well away from the {lm}, {who} takes the most distant {seat} and sits to {act}.",
        "c": "{who} would rather {act} on whichever {seat} is farthest away from the {lm}.",
        "d": "Of all the {seats}, {who} takes the one at the greatest distance from the {lm}, to {act}.",
    },
    "rc.table_near": {
        "a": "{who} sits at the {table} nearest to the {lm} to {act}.",
        "b": "{who} heads for whichever {table} is closest to the {lm}, to {act}.",
        "c": "Picking the {table} beside the {lm}, {who} sits down to {act}.",
    },
    "rc.table_far": {
        "a": "{who} sits at the {table} farthest from the {lm} to {act}.",
        "b": "{who} wants to {act} at the {table} that is the longest walk from the {lm}.",
        "c": "Avoiding the {lm}, {who} takes a seat at the most distant {table} to {act}.",
    },
    "rc.between": {
        "a": "{who} stands between the {lm} and the {lm2} to {act}.",
        "b": "Halfway from the {lm} to the {lm2}, {who} stops to {act}.",
        "c": "{who} decides to {act}, standing in the space between the {lm} and the {lm2}.",
    },
    "rc.facing": {
        "a": "{who} sits facing the {lm} to {act}.",
        "b": "{who} needs a seat that looks straight at the {lm}, to {act}.",
        "c": "Taking a seat turned towards the {lm}, {who} settles down to {act}.",
    },
    "rc.region": {
        "a": "{who} wants to {act} somewhere in the part of the room with the {lm}.",
        "b": "{who} goes over to the {lm} corner and sits down there to {act}.",
        "c": "Near the {lm} there are a few seats; {who} takes one to {act}.",
    },
    "oarc.use_near": {
        "a": "{who} intends to {act}, at the spot nearest the {lm}.",
        "b": "{who} goes to {act}, choosing the place closest to the {lm}.",
        "c": "Staying close to the {lm}, {who} sits down to {act}.",
    },
    "oarc.use_far": {
        "a": "{who} would like to {act}, at the spot farthest from the {lm}.",
        "b": "{who} goes to {act}, choosing the place most distant from the {lm}.",
        "c": "Keeping well away from the {lm}, {who} sits down to {act}.",
    },
    "oass.free_use": {
        "a": "{others} {are} at it already, and now {who} wants to {act} too.",
        "b": "{who} wants to {act} as well, in a place nobody has taken yet.",
        "c": "Since {others} got to it first, {who} looks for a free place to {act}.",
    },
    "oass.wait_use": {
        "a": "{who} would like to {act}.",
        "b": "Now {who} wants to {act} too.",
        "c": "{who} is keen to {act} next.",
    },
    "ss.wait_device": {
        "a": "{who} now wants to {act}.",
        "b": "Between two errands, {who} plans to {act}.",
        "c": "{who} also has to {act}.",
    },
    "oass.switch": {
        "a": "{who} needs some quiet to concentrate and deals with the {thing}.",
        "b": "The noise bothers {who}, who sees to the {thing}.",
        "c": "{who} wants silence in the room and takes care of the {thing}.",
    },
    "ss.free_kind": {
        "a": "{who} takes a {seat} that nobody is sitting on and starts to {act}.",
        "b": "{who} wants to {act} on any {seat} that is still free.",
        "c": "With {others} seated already, {who} finds an empty {seat} to {act}.",
    },
    "ss.join_table": {
        "a": "{who} sits down to keep {others} company at the same {table}.",
        "b": "{others} {are} sitting at a {table}; {who} comes over and sits down there too.",
        "c": "Seeing {others} at a {table}, {who} takes a free seat at that same {table}.",
    },
    "rcss.free_near": {
        "a": "{who} sits on the free {seat} nearest the {lm} to {act}.",
        "b": "{who} is going to {act} on whichever unoccupied {seat} is closest to the {lm}.",
        "c": "Among the {seats} nobody is using, {who} takes the one by the {lm} to {act}.",
    },
    "rcss.beside": {
        "a": "{who} sits down right beside {friend} to {act}.",
        "b": "{who} wants to {act} on a seat next to {friend}'s, in the same row.",
        "c": "Keeping {friend} company, {who} takes the seat at {friend}'s side to {act}.",
    },
    "rcss.across": {
        "a": "{who} sits down opposite {friend} to {act}.",
        "b": "{who} takes the seat facing {friend} across the table to {act}.",
        "c": "Face to face with {friend}, {who} sits to {act}.",
    },
    "pi.front": {
        "a": "{who} waits standing in front of the {lm}.",
        "b": "{who} plants themselves squarely before the {lm}.",
        "c": "{who} goes to stand facing the front of the {lm}.",
    },
    "pi.behind": {
        "a": "{who} waits behind the {lm}.",
        "b": "{who} slips round to the back of the {lm} and stands there.",
        "c": "{who} stands at the rear side of the {lm}.",
    },
    "pi.side": {
        "a": "Judged from the {lm} itself, {who} waits on its {side}.",
        "b": "{who} waits on the {lm}'s own {side}-hand side (the {other_side}, for someone facing it).",
        "c": "Facing the {lm}, {who} goes to stand just off its {other_side} edge.",
    },
    "pi.beside": {
        "a": "{who} waits right next to the {lm}.",
        "b": "{who} stands within arm's reach of the {lm}.",
        "c": "{who} hovers by the {lm}.",
    },
    "pi.between": {
        "a": "{who} waits midway between the {lm} and the {lm2}.",
        "b": "{who} stands in the gap separating the {lm} from the {lm2}.",
        "c": "{who} finds a spot on the line from the {lm} to the {lm2}, in the middle.",
    },
}

_IRREGULAR = {"have": "has", "do": "does", "go": "goes", "be": "is"}


def third_person(phrase: str) -> str:
    """``phrase`` (an infinitive phrase) in the third person singular: its first word conjugated."""
    verb, _, rest = phrase.partition(" ")
    if verb in _IRREGULAR:
        conj = _IRREGULAR[verb]
    elif verb.endswith(("s", "sh", "ch", "x", "z", "o")):
        conj = verb + "es"
    elif verb.endswith("y") and verb[-2:-1] not in "aeiou":
        conj = verb[:-1] + "ies"
    else:
        conj = verb + "s"
    return f"{conj} {rest}".strip()


def all_shape_ids() -> list[str]:
    """Every shape id (``<recipe>.<letter>``)."""
    return [f"{recipe}.{key}" for recipe, shapes in SHAPES.items() for key in shapes]

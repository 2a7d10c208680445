"""The user's instruction as numbered parts, each marked with how far the story has got.

A small model reads "Ava makes coffee, then sits on the couch and drinks it." as one event
and writes it again every turn. Shown as parts with their progress,

    1) [done] Ava makes coffee.
    2) [next] Then Ava sits on the couch and drinks it.

it takes the next part instead. All of it is deterministic text processing; the narrator (the
LLM) still chooses and writes the event.

- ``split_instruction``: sentences, lines and ``;`` make parts, and so does "then" inside a
  sentence (", then", "and then"); a part without a subject of its own ("then sits on the
  couch") or opening with a pronoun ("She then sits.") takes the actors of the part before it;
  "brings it to Ben, who waits on the bench" gives Ben a part (``agents.instruction_subjects``).
- ``part_states``: an event that says which part it was planned for (``HistoryEntry.part``, set by the
  planner) marks that part; one that failed (it could not be placed, or failed in the simulation) leaves the
  part open, and after ``PART_ATTEMPTS`` such failures the part is ``failed`` and the story moves on to the
  next. Any other history event (older traces, the benchmark's cases) is matched by its words: to the not
  yet matched part that shares the most content words with its activity (word stems, object names split at
  ``_``; the same kind of activity, :func:`activity_kind`, counts as :data:`SAME_KIND_SCORE` words when the
  event has every character the part names) and whose actors (the first run of names in it) include one of
  its characters, earliest first on ties; an event sharing no word, or repeating an earlier event's
  activity, matches nothing. A matched part is ``ongoing`` while its event is, ``done`` once the event
  completed or loops (its characters are free again). Only events from index ``since`` on count: the
  instruction can change mid-story, and an event planned under an earlier one ("Ben walks to the kitchen")
  must not mark a part of the new one ("Ben leaves the kitchen") done because their words share stems.
- ``next part``: the first unmatched part whose actors are all free and have no earlier part still open (a
  part naming nobody needs any free character); a part that failed once goes after the untried ones. The
  prompt names it on a line of its own. When parts are left but none is next (what is left waits for busy
  characters), the instruction has nothing for the free characters now: the narrator's rule says to wait,
  and the planner records the wait without asking the model, unless some free characters are *bystanders*
  (no part still open names them: the instruction never did, or their parts are over; and they are not still
  at their last activity, a looping one that is not just idling): they are asked for an event of their own
  (the reply may name only them), so nobody the user did not mention stands idle while the others carry the
  instruction out. Once every part has happened, the free characters the instruction never names (and who
  are not still at a looping activity) are bystanders too: they go on with lives of their own
  (``storyteller.agents.bystanders`` offers them everyday activities); those still at a looping activity of
  their own carry on (the reply may not name them; with nobody else free the step is a wait without a call);
  otherwise the model is asked as before (its rules say what to do with free characters the instruction no
  longer needs). When the next part has actors, the narrator's reply may name only them (the schema's enum):
  a small model otherwise adds whoever else is free.

The patterns here run on the user's text, so none can backtrack super-linearly
(``tests/test_regex_linear.py``): a run of names is one possessive repeat of whole-word names,
a repeat that may start anywhere in a run of spaces is guarded by a lookbehind, and whether a
clause ends with a name is a plain string check. Names are whole words: "Avaand Ben" opens with
no name (the old pattern took "Avaand Ben" for one run).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Literal

from storyteller.agents.action_shortlist import posture
from storyteller.agents.english_words import may_be_verb
from storyteller.agents.instruction_subjects import relative_clause_parts, with_named_subject
from storyteller.agents.messages import HistoryEntry
from storyteller.agents.prompt_templates import PromptLibrary, package_prompts
from storyteller.agents.relation_words import before_relations
from storyteller.agents.step_words import (
    AND_WORD,
    NOT_A_VERB,
    activity_kind,
    intends_only,
    list_steps,
    moves_only,
    no_action,
    states_only,
)

PartState = Literal["done", "ongoing", "failed", "next", ""]

PART_ATTEMPTS = 2
"""Events planned for one part that failed (could not be placed, or failed in the simulation)
before the part is given up (``failed``) and the story moves on to the next."""

_PARTS = re.compile(r"(?<=[.!?;])\s+|\n+")
_THEN = re.compile(
    r"(?:,\s*(?:and\s+)?|(?<!\s)\s+and\s+)(?:then|later|afterwards|after\s+that|eventually|finally),?\s+(?=[A-Za-z])",
    re.IGNORECASE,
)
_WORD = re.compile(r"[A-Za-z]+")
_PRONOUN = re.compile(r"(he|she|they)\b", re.IGNORECASE)
_STOP = frozenset(str.split(
    "the a an and or of to in on at by for with from into onto near next his her their its it "
    "them they he she him then first after before while when that which this these those is are "
    "be being been one some each other another same there here who whom so as if up down out "
    "back over under left right should starts start"
))


SAME_KIND_SCORE = 2
"""What an event and a part of the same kind of activity (:func:`activity_kind`) add to the
words they share when an event is matched to a part."""


@dataclass(frozen=True)
class InstructionPart:
    text: str
    names: tuple[str, ...]  # characters the part mentions, in the order given
    actors: tuple[str, ...]  # who acts: the first run of names ("Ava and Ben"), not the ones
    # the part only refers to ("Ava joins the table of her friend, Ben")
    stems: frozenset[str]  # content-word stems, for matching events


def _stem(word: str) -> str:
    w = word.lower()
    return w[:3] if len(w) > 3 else w


def content_stems(text: str, names: Iterable[str] = ()) -> frozenset[str]:
    """Stems of the words of ``text`` that carry meaning (object names split at ``_``)."""
    skip = {n.lower() for n in names}
    return frozenset(
        _stem(w) for w in _WORD.findall(text.replace("_", " "))
        if len(w) > 2 and w.lower() not in _STOP and w.lower() not in skip
    )


def _mentioned(text: str, names: Sequence[str]) -> tuple[str, ...]:
    words = set(_WORD.findall(text))
    return tuple(n for n in names if n in words)


def _name_run(names: Sequence[str]) -> str:
    """A run of whole-word names joined by commas or "and" ("Ava, Ben and Cleo"); "" without names.
    Possessive: the run never gives names back, so a search over a list of names is linear."""
    known = "|".join(re.escape(n) for n in sorted(names, key=len, reverse=True))
    return rf"\b(?:{known})\b(?:\s*+(?:,|and)\s*+(?:{known})\b)*+" if known else ""


def _leading_subject_pattern(run: str) -> str:
    return rf"\A\s*({run})"


def _clause_cut_pattern(run: str) -> str:
    """Where another character's clause starts alongside (see :func:`_at_the_same_time`)."""
    return (
        rf",?(?<!\s)\s+(?:while|whilst|meanwhile|as)\s+(?=(?:{run})\b)|;\s+(?=(?:{run})\b)"
        rf"|,\s*(?:and\s+)?(?=(?:{run})(?:,[^,.;]{{1,40}},)?\s++[a-z])"  # ", Cleo and Dan talk ...": a new subject
        # and its verb, maybe with an apposition between them (", and Cleo, their waiter, takes ...")
    )


def _ends_with_name(text: str, names: Sequence[str]) -> bool:
    """Whether ``text`` ends with a name as a whole word (then non-word characters at most): the
    end of a run of names. A plain scan, so a clause is read once."""
    end = len(text)
    while end and not _is_word(text[end - 1]):
        end -= 1
    body = text[:end]
    return any(
        body.endswith(n) and (len(body) == len(n) or not _is_word(body[-len(n) - 1])) for n in names if n
    )


def _is_word(ch: str) -> bool:
    return ch.isalnum() or ch == "_"


def _consequence_pattern(run: str) -> str:
    """The names after ", so" ("Ana has taken the chair, so Ben sits on the bench"): what the
    clause before says has happened, and the one after it is what the instruction asks."""
    return rf",\s*+(?:and\s++)?so\s++({run})"


def _actors(text: str, names: Sequence[str]) -> tuple[str, ...]:
    """Who acts in ``text``: the run of names after ", so" when there is one (the clause before
    it is background), else the first run of names."""
    run = _name_run(names)
    if not run:
        return ()
    m = re.search(_consequence_pattern(run), text)
    if m:
        return _mentioned(m.group(1), names)
    m = re.search(run, text)
    return _mentioned(m.group(0), names) if m else ()


def _leading_subject(text: str, names: Sequence[str]) -> str:
    """The run of character names that opens ``text`` ("Ava", "Ava and Ben"), or ""."""
    run = _name_run(names)
    m = re.match(_leading_subject_pattern(run), text) if run else None
    return m.group(1) if m else ""


def split_instruction(
    instruction: str, names: Sequence[str] = (), prompts: PromptLibrary | None = None
) -> list[InstructionPart]:
    """The parts of ``instruction``; ``names``: the story's characters. A part after "then"
    reads ``prompts/story/instruction_then.md`` ("Then ...")."""
    lib = prompts or package_prompts()
    then = lib.render_text("story/instruction_then.md", part="\0")
    parts: list[InstructionPart] = []
    for sentence in _PARTS.split(instruction.strip()):
        sentence = sentence.strip()
        if not sentence:
            continue
        for clause in _at_the_same_time(sentence, names):
            if not _actors(clause, names):  # "She then sits down.": the actors of the part before
                last = next((p for p in reversed(parts) if p.actors), None)
                clause = clause if last is None else with_named_subject(clause, last.actors, last.names, then)
            own, clause = relative_clause_parts(clause, names, _actors(clause, names))
            for text in [*own, clause]:  # "brings it to Ben, who waits on the bench": Ben's part first
                parts.extend(_then_parts(text, names, lib))
    return _with_reasons_joined(parts, names, lib)


def _lower(names: Sequence[str]) -> frozenset[str]:
    return frozenset(n.lower() for n in names)


def _with_reasons_joined(parts: list[InstructionPart], names: Sequence[str], lib: PromptLibrary) -> list[InstructionPart]:
    """``parts`` with each part that states no step of its own (:func:`storyteller.agents.step_words.no_action`:
    "Quinn, free for a moment.", "Femi's bottle is empty.") or, when the next part is no "then"
    step, only what its subject wants (:func:`storyteller.agents.step_words.intends_only`: "Noor wants to
    read. She takes the chair furthest from the fridge.") joined to the part after it, when that
    one's actors are its own or either names none ("Quinn, free for a moment. Switches the telly
    on." is one step: switching the TV on)."""
    then = lib.render_text("story/instruction_then.md", part="\0").split("\0")[0]
    out: list[InstructionPart] = []
    carried = ""
    for k, part in enumerate(parts):
        own = part.text.removeprefix(then)
        own = own[:1].upper() + own[1:] if carried.endswith((".", "!", "?")) else own
        text = f"{carried} {own}" if carried else part.text
        nxt = parts[k + 1] if k + 1 < len(parts) else None
        subject = _leading_subject(text, names)
        joins = no_action(text, subject, _lower(names)) or (
            nxt is not None and intends_only(text, subject) and not nxt.text.startswith(then))
        if nxt is not None and joins and (not part.actors or not nxt.actors or set(nxt.actors) <= set(part.actors)):
            carried = text
            continue
        carried = ""
        out.append(part if text == part.text else
                   InstructionPart(text, _mentioned(text, names), _actors(text, names), content_stems(text, names)))
    return out


def _at_the_same_time(sentence: str, names: Sequence[str]) -> list[str]:
    """``sentence`` cut where another character's clause starts alongside ("Ben works on the
    laptop, while Ava watches TV" is two parts, one per character)."""
    run = _name_run(names)
    if not run:
        return [sentence]
    cut = re.compile(_clause_cut_pattern(run))
    clauses: list[str] = []
    start = 0
    for m in cut.finditer(sentence):
        before = sentence[start : m.start()].strip()
        # a clause of its own has a subject ("Meanwhile, Ben ..." does not cut) and does not end
        # with a name ("Ava, Ben and Cleo dance" stays one)
        if _mentioned(before, names) and not _ends_with_name(before, names):
            clauses.append(before)
            start = m.end()
    clauses.append(sentence[start:].strip())
    clauses = [c for c in clauses if c]
    return [c if c[-1:] in ".!?" or i == len(clauses) - 1 else c + "." for i, c in enumerate(clauses)]


def _and_steps(piece: str, names: Sequence[str]) -> list[str]:
    """``piece`` cut where "and" starts a second action of the same subject ("Ava takes a soda
    out of the fridge and drinks it on the sofa": two steps, one after the other). Cut only when
    one character (or an unnamed subject) acts, the words on each side point to an action label
    (:func:`activity_kind`, read before any relation word: "picks the seat farthest from the
    coffee maker" points to none), the two differ, neither is ``idle`` (waiting while waving is
    one action), the side before names no posture ("sits on the couch and drinks" is drinking
    seated: one step) and does more than go somewhere or say how something is
    (:mod:`storyteller.agents.step_words`). Two characters "chat and watch TV together" at once: not cut."""
    if len(_mentioned(_leading_subject(piece, names), names)) > 1:
        return [piece]
    steps: list[str] = []
    start = 0
    for m in AND_WORD.finditer(piece):
        if m.group(1) in NOT_A_VERB or not may_be_verb(m.group(1)):  # "toast and cereal": no second verb
            continue
        left, right = piece[start : m.start()].strip(), piece[m.end() :].strip()
        before, after = activity_kind(before_relations(left)), activity_kind(before_relations(right))
        if (before is None or after is None or before == after or "idle" in (before, after) or posture(left)
                or moves_only(left, subject := _leading_subject(left, names))
                or states_only(left, subject, _lower(names))):
            continue
        steps.append(left)
        start = m.end()
    steps.append(piece[start:].strip())
    return [s for s in steps if s]


def _then_parts(sentence: str, names: Sequence[str], lib: PromptLibrary) -> list[InstructionPart]:
    """The parts of one clause: "then" starts a new one, and so does "and" before a second action
    of the same subject (:func:`_and_steps`; see :func:`split_instruction`)."""
    parts: list[InstructionPart] = []
    pieces = [step for p in _THEN.split(sentence) if p.strip()
              for item in list_steps(p.strip()) for step in _and_steps(item, names)]
    subject = ""
    for k, piece in enumerate(pieces):
        pronoun = _PRONOUN.match(piece)
        if k > 0 and subject and pronoun:  # "then she and Ben dance": she is the part before's subject
            piece = subject + piece[pronoun.end(1):]
        if k > 0 and not _leading_subject(piece, names):
            piece = f"{subject} {piece}" if subject and piece[:1].islower() else piece[0].lower() + piece[1:]
        if k < len(pieces) - 1 and piece[-1:] not in ".!?;":
            piece += "."
        own = piece if k > 0 else piece.removeprefix("Then ")  # the part's subject opens it
        if k > 0:
            piece = lib.render_text("story/instruction_then.md", part=piece)
        mentioned = _mentioned(piece, names)
        subject = _leading_subject(own, names) or (mentioned[0] if mentioned else subject)
        parts.append(InstructionPart(piece, mentioned, _actors(piece, names), content_stems(piece, names)))
    return parts


_OBJECT_PRONOUNS = frozenset({"them", "their", "theirs", "him", "his", "her", "hers"})
"""Pronouns that point at people the part acts for ("brings them menus", "takes their order")."""


def served_characters(instruction: str, part: str, names: Sequence[str]) -> tuple[str, ...]:
    """The characters ``part`` (a part of ``instruction``) acts for: the names it mentions other
    than its actors ("brings the menu to Ava"), else, when it points at people with a pronoun
    ("brings them menus", "takes their order"; "they" too in a part whose actors are named:
    "Cleo notes down what they want"), the actors of the nearest part before it whose actors are
    others (the guests of the sentence before). () when it names or points at nobody."""
    if not part:
        return ()
    parts = split_instruction(instruction, names)
    index = next((i for i, p in enumerate(parts) if p.text == part), None)
    actors = parts[index].actors if index is not None else _actors(part, names)
    named = tuple(n for n in _mentioned(part, names) if n not in actors)
    if named or index is None:
        return named
    words = {w.lower() for w in _WORD.findall(part)}
    # "they" points at others in a part whose own actors are named ("Cleo notes what they want")
    if not words & _OBJECT_PRONOUNS and not (actors and "they" in words):
        return ()
    before = next((p for p in reversed(parts[:index]) if p.actors and not set(p.actors) & set(actors)), None)
    return before.actors if before is not None else ()


def part_states(
    parts: Sequence[InstructionPart], history: Sequence[HistoryEntry], free: Iterable[str], since: int = 0
) -> list[PartState]:
    """How far the story has got with each part (see the module docstring)."""
    states: list[PartState] = [""] * len(parts)
    failures = [0] * len(parts)
    entries = sorted((h for h in history if h.index >= since), key=lambda e: e.index)
    for h in entries:  # events that say which part they were planned for
        if not h.part:
            continue
        i = next((i for i, p in enumerate(parts) if p.text == h.part and states[i] not in ("done", "ongoing")), -1)
        if i < 0:
            continue
        if h.state == "failed":
            failures[i] += 1
            if failures[i] >= PART_ATTEMPTS:
                states[i] = "failed"
        else:
            states[i] = "ongoing" if h.state == "ongoing" else "done"
    seen: set[str] = set()
    for h in entries:  # the others: by their words
        if h.part or h.state == "failed":
            continue
        said = " ".join(h.activity.lower().split())
        if said in seen:  # the same activity again covers no new part
            continue
        seen.add(said)
        stems = content_stems(h.activity, h.characters)
        kind = activity_kind(h.activity)
        best, best_score = -1, 0
        for i, p in enumerate(parts):
            if states[i] or (p.actors and not set(p.actors) & set(h.characters)):
                continue
            same_kind = kind is not None and kind == activity_kind(p.text) and set(p.names) <= set(h.characters)
            score = len(stems & p.stems) + (SAME_KIND_SCORE if same_kind else 0)  # "with Ben": Ben must be in it
            if score > best_score:
                best, best_score = i, score
        if best >= 0:
            states[best] = "ongoing" if h.state == "ongoing" else "done"
    free_set = set(free)
    waiting: set[str] = set()  # actors of earlier parts not yet done: their later parts wait
    candidates: list[int] = []
    for i, p in enumerate(parts):
        if states[i] in ("done", "failed"):
            continue
        if not states[i] and (
            (p.actors and set(p.actors) <= free_set and not set(p.actors) & waiting) or (not p.actors and free_set)
        ):
            candidates.append(i)
        waiting |= set(p.actors)
    if candidates:  # a part that failed before goes after the untried ones
        states[min(candidates, key=lambda i: (failures[i], i))] = "next"
    return states


@dataclass(frozen=True)
class InstructionProgress:
    """What the narrator's prompt shows of the instruction."""

    text: str  # the instruction: one part as it is, several numbered with their progress
    next_part: str | None  # the part to take now, if any
    next_actors: tuple[str, ...]  # who acts in it (empty: it names nobody, or there is none)
    nothing_for_the_free: bool  # what is left of the instruction is for busy characters only
    bystanders: tuple[str, ...] = ()  # free characters the instruction never names, asked for
    # an event of their own while what is left of it waits for busy characters


def instruction_progress(
    instruction: str, names: Sequence[str] = (), history: Sequence[HistoryEntry] = (), free: Iterable[str] = (),
    *, since: int = 0, prompts: PromptLibrary | None = None, idle: Iterable[str] = (),
) -> InstructionProgress:
    """``since``: the index of the first event planned under ``instruction`` (earlier ones never
    match); ``idle``: free characters whose current action is an idle one (sitting or standing
    there), who count as bystanders even while their last event loops. The texts are ``prompts/story/instruction_*.md`` and ``no_instruction.md``."""
    free = tuple(free)
    lib = prompts or package_prompts()
    parts = split_instruction(instruction, names, lib)
    if not parts:
        return InstructionProgress(lib.render_text("story/no_instruction.md"), None, (), False)
    states = part_states(parts, history, free, since)
    nxt = next((p for p, s in zip(parts, states, strict=True) if s == "next"), None)

    def marked(part: InstructionPart, state: PartState) -> str:
        return lib.render_text("story/instruction_part_marked.md", state=state, part=part.text)

    if len(parts) == 1:
        text = marked(parts[0], states[0]) if states[0] in ("done", "ongoing", "failed") else parts[0].text
    else:
        lines = [marked(p, s) if s else p.text for p, s in zip(parts, states, strict=True)]
        text = "\n" + "\n".join(
            lib.render_text("story/instruction_part_numbered.md", number=i + 1, part=m) for i, m in enumerate(lines)
        )
    if nxt is None:  # waiting for busy characters, or every part has happened
        needed = {n for p, st in zip(parts, states, strict=True) if st not in ("done", "failed") for n in p.names}
        last: dict[str, str] = {}
        for h in sorted(history, key=lambda e: e.index):
            last.update(dict.fromkeys(h.characters, h.state))
        resting = set(idle)
        named = named_in(parts, free)
        bystanders = tuple(
            n for n in free
            if n not in needed and (last.get(n) != "looping" or n in resting)  # still at it: not idle
            and ("" in states or n not in named)  # every part has happened: only the never named
        )
        if bystanders:
            return InstructionProgress(text, None, bystanders, False, bystanders)
        carrying = {n for n in free if n not in named and last.get(n) == "looping" and n not in resting}
        if carrying and "" not in states:  # the never named still at their own activity carry on
            others = tuple(n for n in free if n not in carrying)
            return InstructionProgress(text, None, others, not others)
        return InstructionProgress(text, None, (), "" in states)
    return InstructionProgress(text, nxt.text, nxt.actors, False)


def named_in(parts: Sequence[InstructionPart], everyone: Iterable[str]) -> set[str]:
    """The characters the parts name; a part naming nobody ("Everyone reads.") is any character's,
    so it names ``everyone``."""
    named = {n for p in parts for n in p.names}
    return named | set(everyone) if any(not p.names for p in parts) else named


def earlier_parts(instruction: str, part: str, names: Sequence[str], most: int = 3) -> list[str]:
    """The texts of the parts before ``part`` with an actor of its own, nearest first (at most
    ``most``): what words such as "closes it" point back to. [] when ``part`` is no part."""
    parts = split_instruction(instruction, names)
    at = next((k for k, p in enumerate(parts) if p.text == part), None)
    if at is None:
        return []
    actors = set(parts[at].actors)
    return [p.text for p in reversed(parts[:at]) if actors & set(p.actors)][:most]


def instruction_text(
    instruction: str, names: Sequence[str] = (), history: Sequence[HistoryEntry] = (), free: Iterable[str] = ()
) -> str:
    """The instruction as the narrator's prompt shows it (``InstructionProgress.text``)."""
    return instruction_progress(instruction, names, history, free).text

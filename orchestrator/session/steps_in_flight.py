"""Planning steps in flight: the news each sends the simulation, and when that news counts.

A step runs as a task of the session's task group and reports through a memory channel
(:class:`News`: an LLM call's latency, the characters it claims, its outcome, or that the
planner stopped), never blocking (:func:`post_news`). :class:`StepsInFlight` keeps what each
step in flight has said so far (:class:`Flight`) and answers the simulation's questions at a
frame: must it wait for more news of a step (:meth:`~StepsInFlight.pending`,
:meth:`~StepsInFlight.unsettled`), is a step's outcome applied now (:meth:`~StepsInFlight.due`),
which characters do the steps in flight hold (:meth:`~StepsInFlight.claimed`).

Overlapping steps (``SessionSettings.planners`` = N > 1): a step names its characters as soon
as the narrator's event is accepted (``StepProgress.claim``), before its program is written
and run. Once every step in flight has done so, and fewer than N are in flight, the next step
is requested for the free characters left: their roster shows the claimed ones busy, and the
history shows the claimed events ongoing, so no character is in two events. A step answered
without being run (on resume, from the story log) sends only its outcome; the claim its
narrator made is read from it (:func:`narrated_claim`), so a step asked beside it is asked as
when it ran. ``lockstep`` stays
deterministic with N > 1: it waits for every step in flight to claim or finish before deciding,
and applies every outcome at its request frame. A replay applies each outcome at its recorded
frame (``SessionSettings.applied_frames``, ``recorded_frames``); a resume makes the requests its
trace holds again first, and holds back the outcomes the trace does not show applied meanwhile
(:attr:`StepsInFlight.holding`).

``offline`` pace: the planner reports each LLM call's latency (``StepProgress.llm_call``);
a step's claim is known at its request frame plus the latency of the calls before it, its
outcome applied at its request frame plus the latency of all its calls (or
``offline_latency_s`` per call). The simulation steps ahead freely up to the frame where a
step in flight might next produce news (:meth:`~StepsInFlight.horizon`), and waits there, so
the story is the same however fast the machine or the model is.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import anyio
import structlog
from anyio.streams.memory import MemoryObjectSendStream

from storyteller.agents.llm_port import ReplayMissError
from storyteller.agents.messages import ParsedEvent, PlanningFailure
from storyteller.orchestrator.session.session_types import (
    Outcome,
    PlanningRequest,
    SessionError,
    SessionSettings,
)

_log = structlog.get_logger("storyteller.session")


@dataclass
class Flight:
    """A planning step in flight, as far as its news went."""

    request: PlanningRequest
    latency_s: float = 0.0
    """LLM seconds of the step so far (``offline``: the configured latency per call, if set)."""
    claim: tuple[str, ...] | None = None
    activity: str = ""
    part: str = ""
    claim_frame: int | None = None
    """``offline``: the frame the claim is known at (request frame + the latency before it)."""
    done: bool = False
    outcome: Outcome = None
    due: int | None = None
    """``offline``: the frame the outcome is applied at (request frame + the step's latency)."""


@dataclass(frozen=True)
class News:
    index: int
    kind: Literal["call", "claim", "outcome", "stopped"]
    latency_s: float = 0.0
    characters: tuple[str, ...] = ()
    activity: str = ""
    part: str = ""
    outcome: Outcome = None
    error: BaseException | None = None


class StepNews:
    """:class:`~orchestrator.planning.state.StepProgress` of one step: news to the simulation
    (never blocks)."""

    def __init__(self, index: int, news: MemoryObjectSendStream[News]) -> None:
        self.index = index
        self.news = news

    def llm_call(self, node: str, latency_s: float) -> None:
        post_news(self.news, News(self.index, "call", latency_s=latency_s))

    def claim(self, characters: Sequence[str], activity: str, part: str = "") -> None:
        post_news(self.news, News(self.index, "claim", characters=tuple(characters), activity=activity, part=part))


def narrated_claim(outcome: Outcome) -> tuple[tuple[str, ...], str, str] | None:
    """The claim (characters, activity, part) a step made before it ended with ``outcome``: the
    narrator's event it was accepted with (None: a wait, no event, or a planner without a
    narrator, which claims nothing)."""
    if isinstance(outcome, ParsedEvent) and outcome.narrator_attempts == 0:
        return None  # the one-call planner (no narrator) claims nothing
    if not isinstance(outcome, ParsedEvent | PlanningFailure) or outcome.event is None or outcome.event.is_wait:
        return None
    return tuple(outcome.event.characters), outcome.event.activity, outcome.part


def post_news(news: MemoryObjectSendStream[News], item: News) -> None:
    """Send without waiting; after the simulation ended nobody reads news, and it is dropped."""
    with contextlib.suppress(anyio.ClosedResourceError, anyio.BrokenResourceError):
        news.send_nowait(item)


class StepsInFlight:
    """The steps in flight, by index (``by_index``: the session adds a step when it requests it
    and removes it when its outcome is applied), and when their news counts at a frame."""

    def __init__(self, settings: SessionSettings, fps: int) -> None:
        self.settings = settings
        self.fps = fps
        self.by_index: dict[int, Flight] = {}
        self.holding = False
        """Resumed, and still making the requests the trace holds (``SessionSettings.recorded_requests``):
        an outcome the trace does not show applied is held (the killed process had it in flight
        at each of them). Not in ``offline`` pace, whose outcomes land at a computed frame."""

    def note(self, news: News) -> BaseException | None:
        """Take one piece of news; returns the planner's error when the step stopped on one
        (the step is dropped: the story goes on without a planner, the caller reports it)."""
        fl = self.by_index.get(news.index)
        if fl is None:
            return None
        fps = self.fps
        if news.kind == "call":
            fixed = self.settings.offline_latency_s
            fl.latency_s += fixed if fixed is not None else news.latency_s
        elif news.kind == "claim":
            fl.claim = news.characters
            fl.activity = news.activity
            fl.part = news.part
            fl.claim_frame = fl.request.frame + round(fl.latency_s * fps) if self.settings.pace == "offline" else None
        elif news.kind == "outcome":
            fl.done = True
            fl.outcome = news.outcome
            if self.settings.pace == "offline":
                fl.due = fl.request.frame + round(fl.latency_s * fps)
            said = narrated_claim(news.outcome) if fl.claim is None else None
            if said is not None:  # answered without being run (the story log's answer on resume)
                fl.claim, fl.activity, fl.part = said  # the claim it made when it ran
                fl.claim_frame = fl.due
        else:  # stopped
            # a replay miss is the replayed command's one error line (its diff a record at info level)
            log = _log.info if isinstance(news.error, ReplayMissError) else _log.error
            log("planner_stopped", step=news.index, error=f"{type(news.error).__name__}: {news.error}")
            del self.by_index[news.index]
            return news.error
        return None

    def recorded_due(self, index: int) -> int | None:
        due = self.settings.recorded_frames.get(index)
        if due is None and self.settings.applied_frames is not None and index < len(self.settings.applied_frames):
            due = self.settings.applied_frames[index]
        return due

    def replaying(self) -> bool:
        return self.settings.applied_frames is not None

    def horizon(self, fl: Flight) -> int:
        """``offline``: nothing of ``fl`` can happen before this frame (its calls so far took that long)."""
        return fl.request.frame + round(fl.latency_s * self.fps)

    def pending(self, fl: Flight, frame: int) -> bool:
        """More news of ``fl`` is needed before ``frame`` steps: its outcome may be applied then."""
        due = self.recorded_due(fl.request.index)
        if due is not None and due < frame:
            raise SessionError(
                f"replay: step {fl.request.index} was applied at frame {due}, "
                f"but its request was made at frame {fl.request.frame}"
            )
        if fl.done:
            return False
        if due is not None:
            return due == frame
        if self.replaying():
            return False  # requested but never applied in the recorded run
        pace = self.settings.pace
        if pace == "lockstep":
            return True
        if pace == "offline":
            return self.horizon(fl) <= frame
        return False

    def unsettled(self, fl: Flight, frame: int) -> bool:
        """More news of ``fl`` is needed to know whether it named its characters as of ``frame``."""
        if fl.done or self.replaying():
            return False
        pace = self.settings.pace
        if pace == "lockstep":
            return fl.claim is None
        if pace == "offline":
            if fl.claim is not None and fl.claim_frame is not None and fl.claim_frame <= frame:
                return False
            return self.horizon(fl) <= frame
        return False

    def due(self, fl: Flight, frame: int) -> bool:
        """``fl``'s outcome is applied at ``frame`` (before the world steps)."""
        due = self.recorded_due(fl.request.index)
        if due is not None:
            return due == frame
        if self.replaying() or (self.holding and self.settings.pace != "offline"):
            return False
        if self.settings.pace == "offline":
            if fl.due is not None and fl.due < frame:
                raise SessionError(f"offline: step {fl.request.index} landed at frame {fl.due}, before frame {frame}")
            return fl.due == frame
        return self.settings.pace == "lockstep" or fl.done

    def claimed(self, frame: int) -> dict[str, Flight] | None:
        """Character -> the step in flight it takes part in, as of ``frame``; None while a step
        in flight has not named its characters yet (nothing can be planned beside it)."""
        out: dict[str, Flight] = {}
        offline = self.settings.pace == "offline" and not self.replaying()  # a replay: the recorded schedule
        for fl in self.by_index.values():
            if fl.claim is not None and (not offline or (fl.claim_frame is not None and fl.claim_frame <= frame)):
                names: Sequence[str] = fl.claim
            elif fl.done and (not offline or (fl.due is not None and fl.due <= frame)):
                names = fl.outcome.event.characters if isinstance(fl.outcome, ParsedEvent) else ()
            else:
                return None
            out.update((n, fl) for n in names)
        return out

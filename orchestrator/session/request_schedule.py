"""The recorded requests a story session makes again, each at its frame and phase (``planners`` > 1).

A replay of a run with overlapping steps makes every request its trace holds
(``SessionSettings.schedule``) and no other. A resumed run makes the ones its trace holds for
the steps after its checkpoint (``SessionSettings.recorded_requests``: the killed process traced
them before its last checkpoint reached the disk), without tracing them again, and then asks
live; until then, outcomes the trace does not show applied are held
(``storyteller.orchestrator.session.steps_in_flight.StepsInFlight.holding``), as the killed process still
had them in flight. So a step's request is in the trace once, and the resumed story is the one
the trace tells. Each request comes at the step and beside the steps in flight it was recorded
with, or the session stops with a :class:`SessionError` naming both.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

from storyteller.orchestrator.session.session_types import (
    RecordedRequest,
    RequestPhase,
    SessionError,
    SessionSettings,
)


class RequestSchedule:
    """The recorded requests not made yet, in trace order; ``then_live``: a resume's (live
    requests follow the last), else a replay's (no other request is made)."""

    def __init__(self, recorded: Iterable[RecordedRequest], *, then_live: bool) -> None:
        self.pending = list(recorded)
        self.then_live = then_live
        self.what = "resume" if then_live else "replay"

    @classmethod
    def of(cls, settings: SessionSettings, *, after_step: int = 0) -> RequestSchedule | None:
        """What a session on ``settings`` follows (None: it asks live); ``after_step``: a resumed
        session's next step (the checkpoint's), the requests of earlier ones are behind it."""
        if settings.schedule is not None:
            return cls(settings.schedule, then_live=False)
        left = [r for r in settings.recorded_requests if r.step >= after_step]
        return cls(left, then_live=True) if left else None

    @property
    def done(self) -> bool:
        """A resume made all its recorded requests: the session asks live from now on."""
        return self.then_live and not self.pending

    def take(self, frame: int, phase: RequestPhase) -> RecordedRequest | None:
        """The next request recorded at ``frame`` and ``phase`` (None: no more there). Raises
        :class:`SessionError` when the session is past the frame of the next one."""
        if self.pending and (self.pending[0].frame, self.pending[0].phase) == (frame, phase):
            return self.pending.pop(0)
        if self.pending and self.pending[0].frame < frame:
            first = self.pending[0]
            raise SessionError(f"{self.what}: step {first.step} was requested at frame {first.frame}, "
                               f"which the {self.what} passed")
        return None

    def check(self, rec: RecordedRequest, step: int, in_flight: Sequence[int]) -> None:
        """Raise :class:`SessionError` unless ``rec`` is for ``step`` beside the steps ``in_flight``."""
        if rec.step != step or tuple(sorted(in_flight)) != rec.after:
            raise SessionError(
                f"{self.what}: step {rec.step} was requested at frame {rec.frame} beside steps {list(rec.after)}, "
                f"but the {self.what} is at step {step} beside {sorted(in_flight)}"
            )

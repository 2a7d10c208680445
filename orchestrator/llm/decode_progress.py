"""Limit a local model call by its progress, not by a fixed wall-clock timeout.

Guarantee: a call is stopped (:class:`~storyteller.orchestrator.llm.local_errors.LocalModelStalledError`,
naming the measured rate and the floor) only when

- reading the prompt takes longer than its allowance, :meth:`ProgressFloor.prompt_allowance_s`
  (:data:`PROMPT_BASE_S` plus the prompt's new tokens at :data:`MIN_PROMPT_TOK_S`);
- after the prompt, fewer tokens than :data:`MIN_DECODE_TOK_S` x :data:`DECODE_WINDOW_S` were
  decoded in the last :data:`DECODE_WINDOW_S` seconds (judged once a full window has passed);
- or the call's hard cap passes (a ``timeout_s`` set in the config; unset, the time the floors
  themselves allow: :func:`default_hard_cap_s`).

So a call that is slow but keeps decoding at the floor or faster runs to its end. The floors
are far below the model's speed on a busy machine (the 0.5B model reads ~150 and writes ~37
tokens/s on 2 idle cores, ~3x less with a core taken by another process).

Checks happen where llama.cpp hands control back to Python: before each batch of the prompt
(``n_batch`` tokens) and before each generated token. llama.cpp cannot be interrupted inside
one evaluation, so a stall is seen when that evaluation returns. The clock is injected.
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from storyteller.orchestrator.llm.local_errors import StallPhase

MIN_DECODE_TOK_S = 0.5
"""Floor of the decode rate after the prompt, tokens per second, over :data:`DECODE_WINDOW_S`."""
DECODE_WINDOW_S = 30.0
"""Seconds of decoding the rate is measured over."""
MIN_PROMPT_TOK_S = 5.0
"""Floor of the prompt reading rate, tokens per second (on top of :data:`PROMPT_BASE_S`)."""
PROMPT_BASE_S = 30.0
"""Seconds every prompt may take whatever its length."""
CHARS_PER_TOKEN = 3.0
"""Characters per token, to estimate a prompt's tokens before it is tokenised."""


@dataclass(frozen=True)
class ProgressFloor:
    """The floors a local call is held to (defaults: the module constants)."""

    decode_tok_s: float = MIN_DECODE_TOK_S
    window_s: float = DECODE_WINDOW_S
    prompt_tok_s: float = MIN_PROMPT_TOK_S
    prompt_base_s: float = PROMPT_BASE_S

    def prompt_allowance_s(self, prompt_tokens: int) -> float:
        return self.prompt_base_s + prompt_tokens / self.prompt_tok_s

    def describe(self) -> str:
        return (f"decode >= {self.decode_tok_s:g} tok/s over {self.window_s:g} s; prompt within "
                f"{self.prompt_base_s:g} s + 1 s per {self.prompt_tok_s:g} tokens")


def default_hard_cap_s(prompt_chars: int, max_tokens: int, floor: ProgressFloor = ProgressFloor()) -> float:
    """The longest a call that keeps to the floors can take: its prompt allowance (tokens
    estimated from characters) plus ``max_tokens`` at the decode floor plus one window."""
    prompt_tokens = round(prompt_chars / CHARS_PER_TOKEN)
    return round(floor.prompt_allowance_s(prompt_tokens) + max_tokens / floor.decode_tok_s + floor.window_s, 1)


class ProgressWatch:
    """Follows one call: :meth:`prompt_started` with the tokens to read, :meth:`prompt_done`,
    :meth:`decoded` per token; :meth:`check` raises when the call broke a floor."""

    def __init__(self, model: str, hard_cap_s: float, floor: ProgressFloor = ProgressFloor(),
                 clock: Callable[[], float] = time.monotonic, local_threads: dict[str, Any] | None = None) -> None:
        self.model = model
        self.hard_cap_s = hard_cap_s
        self.floor = floor
        self._clock = clock
        self._threads = local_threads
        self.start = clock()
        self.prompt_tokens: int | None = None
        self.prompt_end: float | None = None
        self.tokens = 0
        self._recent: deque[float] = deque()  # times of the tokens decoded in the last window

    @property
    def in_prompt(self) -> bool:
        return self.prompt_end is None

    def prompt_started(self, tokens: int) -> None:
        self.prompt_tokens = tokens

    def prompt_done(self) -> None:
        self.prompt_end = self._clock()

    def decoded(self, tokens: int = 1) -> None:
        now = self._clock()
        self.tokens += tokens
        self._recent.extend([now] * tokens)

    def check(self) -> None:
        now = self._clock()
        f = self.floor
        if self.prompt_end is None:
            n = self.prompt_tokens or 0
            allowance = f.prompt_allowance_s(n)
            took = now - self.start
            if took > allowance:
                rate = n / took if took > 0 else None
                self._stall("prompt", rate, f.prompt_tok_s,
                            f"local model read {n} prompt tokens for {took:.1f} s, past its allowance of "
                            f"{allowance:.1f} s ({f.prompt_base_s:g} s + {n} tokens at the floor of "
                            f"{f.prompt_tok_s:g} tok/s)")
        else:
            while self._recent and self._recent[0] < now - f.window_s:
                self._recent.popleft()
            if now - self.prompt_end >= f.window_s:
                rate = len(self._recent) / f.window_s
                if rate < f.decode_tok_s:
                    self._stall("decode", rate, f.decode_tok_s,
                                f"local model decoded {rate:.2f} tok/s over the last {f.window_s:g} s, under "
                                f"the floor of {f.decode_tok_s:g} tok/s ({self.tokens} tokens after the prompt)")
        if now - self.start > self.hard_cap_s:
            rate = self._rate(now)
            shown = "not started" if rate is None else f"{rate:.2f} tok/s"
            self._stall("hard_cap", rate, f.decode_tok_s,
                        f"local model ran past its hard cap of {self.hard_cap_s:.1f} s (decoding {shown}, floor "
                        f"{f.decode_tok_s:g} tok/s; {self.tokens} tokens after the prompt)")

    def _rate(self, now: float) -> float | None:
        if self.prompt_end is None or now <= self.prompt_end:
            return None
        return self.tokens / (now - self.prompt_end)

    def _stall(self, phase: StallPhase, rate: float | None, floor: float, message: str) -> None:
        # imported here: it brings litellm, which `storyteller model info` (the floors) does not need
        from storyteller.orchestrator.llm.local_errors import LocalModelStalledError

        if self._threads is not None:
            later = "".join(f", then {n}" for n in self._threads.get("rechosen", ()))
            message += f"; {self._threads['threads']} thread(s){later}"
        raise LocalModelStalledError(message, model=self.model, phase=phase, rate_tok_s=rate,
                                     floor_tok_s=floor, local_threads=self._threads)

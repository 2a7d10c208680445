"""The errors the embedded model's provider raises, and which of them a retry can fix.

They are litellm exception types, so litellm passes them through to the client unchanged
(type and attributes). The embedded model is deterministic and runs on this machine: the same
request gives the same answer at the same speed, so the only local errors worth another
attempt are :class:`LocalModelBusyError` (the machine could not give the model memory or a file
at that moment). A call stopped for lack of progress (:class:`LocalModelStalledError`) is not
retried: a new attempt would start from zero at the same speed.
"""

from __future__ import annotations

import os
from typing import Any, Literal

os.environ.setdefault("LITELLM_LOCAL_MODEL_COST_MAP", "True")  # before litellm's first import: no fetch

from litellm.exceptions import ServiceUnavailableError, Timeout

StallPhase = Literal["prompt", "decode", "hard_cap"]


class LocalModelStalledError(Timeout):
    """A local call stopped because it made too little progress: reading the prompt slower
    than its allowance, decoding slower than the floor over the window, or past the hard cap.
    The message names the measured rate and the floor."""

    def __init__(self, message: str, *, model: str, phase: StallPhase, rate_tok_s: float | None,
                 floor_tok_s: float, local_threads: dict[str, Any] | None = None) -> None:
        super().__init__(message=message, model=model, llm_provider="local")
        self.phase: StallPhase = phase
        self.rate_tok_s = rate_tok_s
        self.floor_tok_s = floor_tok_s
        self.local_threads = local_threads


class LocalModelBusyError(ServiceUnavailableError):
    """The machine could not give the model what it needed (memory, a file) at that moment;
    another attempt may succeed."""

    def __init__(self, message: str, *, model: str) -> None:
        super().__init__(message=message, llm_provider="local", model=model)


def local_error_retryable(exc: BaseException) -> bool:
    """Whether another attempt on the same local model may succeed after ``exc``."""
    return isinstance(exc, LocalModelBusyError)

"""Which LLM errors are worth retrying, and how long to wait between attempts.

We own the retry policy instead of litellm's ``num_retries`` (which also retries 400/401 and
makes 2N+1 attempts). Transient: rate limit (429), timeout, connection error, 5xx, and a
response that is empty or whose JSON is truncated or unparsable. Permanent: 400, 401, 403,
404, 422 and anything else we do not recognise as transient. A permanent error is never
retried on the same model; the next fallback model is still tried.

The embedded model (``local/...``) is deterministic and runs here: the same request gives the
same answer at the same speed, so of its errors only a shortage of memory or a file is
transient (:func:`storyteller.orchestrator.llm.local_errors.local_error_retryable`); a call stopped for
lack of progress, an unusable answer or a llama.cpp failure is permanent.
"""

from __future__ import annotations

import random
from collections.abc import Iterator, Sequence
from typing import Literal

from storyteller.agents.llm_port import LLMError, LLMUnavailableError
from storyteller.orchestrator.llm.config import RetryConfig

ErrorClass = Literal["transient", "permanent"]


class InvalidResponseError(Exception):
    """The provider answered, but the answer is unusable (empty, truncated or not JSON)."""

    def __init__(self, message: str, text: str = "") -> None:
        super().__init__(message)
        self.text = text


_TRANSIENT_STATUS = {408, 409, 425, 429}
_PERMANENT_STATUS = {400, 401, 403, 404, 405, 413, 415, 422}


def _litellm_transient_types() -> tuple[type[BaseException], ...]:
    from litellm import exceptions

    return (
        exceptions.RateLimitError,
        exceptions.Timeout,
        exceptions.APIConnectionError,
        exceptions.InternalServerError,
        exceptions.ServiceUnavailableError,
        exceptions.BadGatewayError,
    )


def _litellm_permanent_types() -> tuple[type[BaseException], ...]:
    from litellm import exceptions

    return (
        exceptions.BadRequestError,  # includes ContextWindowExceeded, ContentPolicyViolation
        exceptions.AuthenticationError,
        exceptions.PermissionDeniedError,
        exceptions.NotFoundError,
        exceptions.UnprocessableEntityError,
    )


def classify_error(exc: BaseException, *, local: bool = False) -> ErrorClass:
    """Decide whether ``exc`` (raised by one attempt) may succeed if the same call is repeated;
    ``local``: the attempt was on the embedded model (see the module doc)."""
    if local:
        from storyteller.orchestrator.llm.local_errors import local_error_retryable

        return "transient" if local_error_retryable(exc) else "permanent"
    if isinstance(exc, InvalidResponseError | TimeoutError | ConnectionError):
        return "transient"
    if isinstance(exc, _litellm_permanent_types()):
        return "permanent"
    if isinstance(exc, _litellm_transient_types()):
        return "transient"
    status = getattr(exc, "status_code", None)
    if isinstance(status, int):
        if status in _TRANSIENT_STATUS or status >= 500:
            return "transient"
        if status in _PERMANENT_STATUS or 400 <= status < 500:
            return "permanent"
    return "permanent"


class RetryPolicy:
    """Exponential backoff with seeded jitter. One policy object per (call, model)."""

    def __init__(self, config: RetryConfig, *, salt: int = 0) -> None:
        self.config = config
        self._rng = random.Random(config.seed * 1_000_003 + salt)

    @property
    def max_attempts(self) -> int:
        return self.config.max_attempts

    def delay_s(self, retry_index: int) -> float:
        """Seconds to wait before retry number ``retry_index`` (1 = the second attempt)."""
        if retry_index < 1:
            raise ValueError("retry_index starts at 1")
        c = self.config
        base = min(c.backoff_max_s, c.backoff_base_s * 2.0 ** (retry_index - 1))
        factor = 1.0 + c.jitter * (2.0 * self._rng.random() - 1.0)
        return max(0.0, min(c.backoff_max_s, base * factor))

    def delays(self) -> Iterator[float]:
        """The delays before attempts 2..max_attempts."""
        for k in range(1, self.config.max_attempts):
            yield self.delay_s(k)


def failed_call_error(node: str, failures: Sequence[tuple[str, str, str]], *, unavailable: bool) -> LLMError:
    """The error a call raises when every attempt failed: ``failures`` are (model, error type
    name, redacted message) per attempt; ``unavailable`` when every one was an
    :class:`LLMUnavailableError`. The live client and the replay both build it here, so a
    replayed failure has the recorded message exactly."""
    if unavailable:
        msgs = "; ".join(dict.fromkeys(message for _, _, message in failures))
        return LLMUnavailableError(f"node {node}: no usable model: {msgs}")
    per_model = {model: f"{kind}: {message[:200]}" for model, kind, message in failures}
    summary = "; ".join(f"{m} -> {e}" for m, e in per_model.items())
    return LLMError(f"node {node}: all {len(failures)} attempts failed ({summary})")


def unavailable_error_names() -> frozenset[str]:
    """Names of :class:`LLMUnavailableError` and its subclasses (as a trace records them)."""
    import storyteller.orchestrator.llm.model_weights  # noqa: F401  # defines subclasses (weights missing or corrupt)

    names, todo = set(), [LLMUnavailableError]
    while todo:
        cls = todo.pop()
        names.add(cls.__name__)
        todo.extend(cls.__subclasses__())
    return frozenset(names)

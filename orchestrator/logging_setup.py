"""structlog configuration, done once per process by the CLI (or a test that wants it).

Console rendering when stderr is a terminal, one JSON object per line otherwise. ``sim/``
and ``tools/`` never log; they return diagnostics that the orchestrator logs.

Log values often carry text from a model or an event program (an activity, an error message),
so every string value and key goes through :func:`storyteller.orchestrator.safe_text.plain` before it is
rendered (:func:`escape_controls`): a log record is one line with no control character (no
terminal escape sequence reaches a console), whichever renderer; a formatted traceback keeps
its line breaks.
"""

from __future__ import annotations

import logging
import sys
from typing import TextIO

import structlog

from storyteller.orchestrator.safe_text import plain

_configured = False
_MULTILINE_KEYS = frozenset({"exception", "stack"})  # formatted tracebacks keep their line breaks


def escape_controls(_logger: object, _method: str, event_dict: structlog.typing.EventDict) -> structlog.typing.EventDict:
    """A structlog processor: every string key and value with its control characters shown as
    escapes (``plain``); nested values are rendered by ``repr``/JSON, which escape them already."""
    return {
        plain(key): plain(value, keep_newlines=key in _MULTILINE_KEYS) if isinstance(value, str) else value
        for key, value in event_dict.items()
    }


class _StderrLogger:
    """Writes each line to whatever ``sys.stderr`` is *now*.

    Binding the stream once at configuration time breaks when stderr is swapped later (a test
    runner capturing output closes its stream; the next log line would hit a closed file)."""

    def msg(self, message: str) -> None:
        print(message, file=sys.stderr, flush=True)

    log = debug = info = warning = warn = error = critical = exception = fatal = failure = msg


def _stderr_logger_factory(*_args: object) -> _StderrLogger:
    return _StderrLogger()


def configure_logging(level: str | int = "INFO", *, json: bool | None = None, stream: TextIO | None = None) -> None:
    """Configure structlog (idempotent: later calls are ignored unless ``force_logging_reset``).

    ``json=None`` picks JSON unless ``stream`` (default stderr) is a TTY."""
    global _configured
    if _configured:
        return
    out = stream if stream is not None else sys.stderr  # only to decide the rendering
    use_json = (not out.isatty()) if json is None else json
    numeric = logging.getLevelName(level.upper()) if isinstance(level, str) else level
    if not isinstance(numeric, int):
        raise ValueError(f"unknown log level {level!r}")
    renderer: structlog.typing.Processor = (
        structlog.processors.JSONRenderer() if use_json else structlog.dev.ConsoleRenderer(colors=out.isatty())
    )
    structlog.configure(
        processors=[
            structlog.contextvars.merge_contextvars,
            structlog.processors.add_log_level,
            structlog.processors.TimeStamper(fmt="iso", utc=True),
            structlog.processors.StackInfoRenderer(),
            structlog.processors.format_exc_info,
            escape_controls,
            renderer,
        ],
        wrapper_class=structlog.make_filtering_bound_logger(numeric),
        logger_factory=structlog.PrintLoggerFactory(file=stream) if stream is not None else _stderr_logger_factory,
        cache_logger_on_first_use=False,  # lets tests reset the configuration
    )
    # litellm logs through stdlib logging; keep it quiet unless we are debugging.
    logging.getLogger("LiteLLM").setLevel(max(numeric, logging.WARNING))
    _configured = True


def force_logging_reset() -> None:
    """Allow :func:`configure_logging` to run again (tests)."""
    global _configured
    _configured = False
    structlog.reset_defaults()

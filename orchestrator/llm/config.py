"""Run configuration: per-node LLM settings from a TOML file plus environment overrides.

Layout of the TOML file (every table and key is optional)::

    [llm]                       # defaults for every node
    model = "local/qwen2.5-coder-0.5b"
    temperature = 0.0
    max_tokens = 1024            # a cap: requests may ask for fewer
    timeout_s = 120.0           # per attempt; for a local model a hard cap only (its calls are
                                # limited by progress: storyteller.orchestrator.llm.decode_progress); unset,
                                # a local call gets what the progress floors allow (local_timeout_s)
    fallbacks = []              # tried in order after ``model`` has used up its retries
    api_base = "http://127.0.0.1:8080/v1"   # optional
    api_key_env = "OPENAI_API_KEY"          # optional: NAME of the variable holding the key

    [llm.retry]
    max_attempts = 3            # attempts per model for transient errors (1 = no retry)
    backoff_base_s = 0.5        # delay before retry k (k >= 1) = base * 2**(k-1), capped
    backoff_max_s = 8.0
    jitter = 0.25               # each delay is scaled by a factor drawn in [1-jitter, 1+jitter]
    seed = 0                    # seed of the jitter RNG (deterministic delays)

    [nodes.narrator]            # per node: describer, narrator, event_parser, planner
    model = "openai/gpt-4o-mini"
    fallbacks = ["local/qwen2.5-coder-0.5b"]
    [nodes.narrator.retry]
    max_attempts = 5

    [trace]
    fsync = "always"            # always | close | never

Bounded: the file is read within ``MAX_CONFIG_BYTES`` (a regular file, ``storyteller.sim.bounded_files``),
nesting that overflows the TOML reader and integers too long to convert are a
:class:`ConfigError`, and every number is finite and within its field's range: a delay or a
timeout is at most ``MAX_DELAY_S`` / ``MAX_TIMEOUT_S`` seconds, never infinite.

Secrets never live in the file: a key named like ``api_key``, ``token``, ``secret`` or
``password`` is a :class:`ConfigError`; name the environment variable with ``api_key_env``.

Environment overrides (applied after the file): ``STORYTELLER_CONFIG`` (file path, when no
explicit path is given), ``STORYTELLER_MODEL`` (every node), ``STORYTELLER_<NODE>_MODEL``,
``STORYTELLER_<NODE>_FALLBACKS`` (comma separated), ``STORYTELLER_<NODE>_TEMPERATURE``,
``STORYTELLER_<NODE>_MAX_TOKENS``, ``STORYTELLER_<NODE>_TIMEOUT_S``,
``STORYTELLER_<NODE>_API_BASE`` with ``<NODE>`` one of DESCRIBER, NARRATOR, EVENT_PARSER,
PLANNER.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, get_args

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from storyteller.agents.llm_port import NodeName
from storyteller.sim.validation_text import problem_field, problem_message

DEFAULT_MODEL = "local/qwen2.5-coder-0.5b"
NODE_NAMES: tuple[NodeName, ...] = get_args(NodeName)
FsyncPolicy = Literal["always", "close", "never"]
"""When trace appends reach the disk: after every record, once at close, or when the OS decides."""
_SECRET_WORDS = frozenset({"key", "apikey", "token", "secret", "password", "passwd", "credential", "credentials"})


class ConfigError(ValueError):
    """A configuration problem, reported as one sentence naming the source and the field.

    A ``ValueError``, so the commands that report bad inputs as ``ValueError`` (``plan`` and
    ``run`` opening their LLM port) report it as one line with exit code 2, not a traceback."""

    def __init__(self, source: str, field: str | None, message: str) -> None:
        self.source = source
        self.field = field
        self.message = message
        where = f"{source}: {field}" if field else source
        super().__init__(f"{where}: {message}")


MAX_CONFIG_BYTES = 1024 * 1024
"""Bytes of a config file (a full one takes about 1 KB)."""
MAX_DELAY_S = 600.0
"""Seconds of the longest retry delay a config may ask for."""
MAX_TIMEOUT_S = 86_400.0
"""Seconds of the longest per-attempt timeout a config may ask for (a day)."""


class RetryConfig(BaseModel):
    """Retry policy for transient errors of one model (rate limit, timeout, connection, 5xx)."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    max_attempts: int = Field(default=3, ge=1, le=20, description="Attempts per model, >= 1.")
    backoff_base_s: float = Field(default=0.5, ge=0.0, le=MAX_DELAY_S, description="First retry delay, seconds.")
    backoff_max_s: float = Field(default=8.0, ge=0.0, le=MAX_DELAY_S, description="Cap of one delay, seconds.")
    jitter: float = Field(default=0.25, ge=0.0, le=1.0, description="Relative jitter of a delay.")
    seed: int = Field(default=0, ge=-(2**63), lt=2**63, description="Seed of the jitter RNG.")


class NodeConfig(BaseModel):
    """The resolved LLM settings of one graph node."""

    model_config = ConfigDict(frozen=True, extra="forbid", allow_inf_nan=False)

    model: str = Field(default=DEFAULT_MODEL, min_length=1)
    temperature: float = Field(default=0.0, ge=0.0, le=2.0)
    max_tokens: int = Field(
        default=1024, gt=0, le=32768,
        description="Cap on generated tokens; a request's own max_tokens can only lower it.",
    )
    timeout_s: float = Field(
        default=120.0, gt=0.0, le=MAX_TIMEOUT_S,
        description="Per-attempt timeout, seconds. For a local model a hard cap: its calls are limited by "
        "their progress (orchestrator.llm.decode_progress); when not set, a local call may take what the "
        "progress floors allow, at least this (orchestrator.llm.local_model.local_timeout_s).",
    )
    fallbacks: tuple[str, ...] = ()
    api_base: str | None = None
    api_key_env: str | None = Field(
        default=None, description="Name of the environment variable that holds the API key."
    )
    retry: RetryConfig = RetryConfig()

    @model_validator(mode="after")
    def _check(self) -> NodeConfig:
        if any(not m.strip() for m in self.fallbacks):
            raise ValueError("fallback model names must not be empty")
        if self.api_key_env is not None and not self.api_key_env.replace("_", "").isalnum():
            raise ValueError("api_key_env must be an environment variable NAME, not a key")
        return self

    @property
    def models(self) -> tuple[str, ...]:
        """The primary model followed by its fallbacks, in the order they are tried."""
        return (self.model, *self.fallbacks)


class TraceConfig(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")

    fsync: FsyncPolicy = Field(
        default="always",
        description="When trace appends are fsync'ed to disk: always (each record, in the trace writer's own "
        "thread; the run waits for it before it relies on the record), close (when the trace closes), never.",
    )


class StorytellerConfig(BaseModel):
    """Whole-run configuration. ``nodes`` always holds all four node names."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    nodes: dict[NodeName, NodeConfig]
    trace: TraceConfig = TraceConfig()
    source: str = Field(default="<defaults>", description="Where the config came from.")

    def node(self, name: NodeName) -> NodeConfig:
        return self.nodes[name]


def default_config() -> StorytellerConfig:
    """Every node on the embedded local model."""
    return StorytellerConfig(nodes={n: NodeConfig() for n in NODE_NAMES})


def _find_secret(data: Any, prefix: str) -> str | None:
    if isinstance(data, Mapping):
        for key, value in data.items():
            dotted = f"{prefix}.{key}" if prefix else str(key)
            lowered = str(key).lower()
            if lowered != "api_key_env" and _SECRET_WORDS & set(lowered.replace("-", "_").split("_")):
                return dotted
            found = _find_secret(value, dotted)
            if found:
                return found
    return None


def _first_error(exc: ValidationError, prefix: str) -> tuple[str, str]:
    err = exc.errors()[0]
    return problem_field(err, prefix), problem_message(err)


def _build_node(base: Mapping[str, Any], override: Mapping[str, Any], source: str, prefix: str) -> NodeConfig:
    merged: dict[str, Any] = {k: v for k, v in base.items() if k != "retry"}
    merged.update({k: v for k, v in override.items() if k != "retry"})
    retry: dict[str, Any] = {}
    for part in (base.get("retry"), override.get("retry")):
        if part is not None:
            if not isinstance(part, Mapping):
                raise ConfigError(source, f"{prefix}.retry", "expected a table")
            retry.update(part)
    if retry:
        merged["retry"] = retry
    try:
        return NodeConfig.model_validate(merged)
    except ValidationError as exc:
        field, msg = _first_error(exc, prefix)
        raise ConfigError(source, field, msg) from None


_ENV_FIELDS: dict[str, str] = {
    "MODEL": "model",
    "FALLBACKS": "fallbacks",
    "TEMPERATURE": "temperature",
    "MAX_TOKENS": "max_tokens",
    "TIMEOUT_S": "timeout_s",
    "API_BASE": "api_base",
}


PREFIX_SLOTS_ENV = "STORYTELLER_LOCAL_PREFIX_SLOTS"


def prefix_slots(env: Mapping[str, str]) -> int:
    """``STORYTELLER_LOCAL_PREFIX_SLOTS`` (default 3): Llama instances per embedded model, each
    keeping the KV cache of the last prompt it saw. A few ASCII digits, or a :class:`ConfigError`
    that names the variable; :func:`load_config` checks it, so a run stops before its setup."""
    raw = env.get(PREFIX_SLOTS_ENV, "3").strip()
    if not (raw.isascii() and raw.isdigit()) or len(raw) > 3:
        raise ConfigError("environment", PREFIX_SLOTS_ENV, f"must be a whole number >= 1, got {raw[:20]!r}")
    return max(1, int(raw))


def _env_overrides(node: NodeName, env: Mapping[str, str]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    if env.get("STORYTELLER_MODEL"):
        out["model"] = env["STORYTELLER_MODEL"]
    for suffix, field in _ENV_FIELDS.items():
        value = env.get(f"STORYTELLER_{node.upper()}_{suffix}")
        if value is None or value == "":
            continue
        if field == "fallbacks":
            out[field] = [m.strip() for m in value.split(",") if m.strip()]
        else:
            out[field] = value
    return out


def _read_toml(path: Path, source: str) -> dict[str, Any]:
    """The TOML table of a config file, read within :data:`MAX_CONFIG_BYTES` (``storyteller.sim.bounded_files``)."""
    from storyteller.sim.bounded_files import BoundedFileError, load_bounded_toml, read_bounded_bytes

    try:
        return load_bounded_toml(read_bounded_bytes(path, MAX_CONFIG_BYTES, source), source)
    except BoundedFileError as exc:
        problem = "config file not found" if exc.problem == "file not found" else exc.problem
        raise ConfigError(source, None, problem) from None


def load_config(path: Path | str | None = None, env: Mapping[str, str] | None = None) -> StorytellerConfig:
    """Read the config file (``path``, else ``$STORYTELLER_CONFIG``, else defaults) and apply
    environment overrides. Raises :class:`ConfigError` with a one-line message on any problem."""
    env = os.environ if env is None else env
    prefix_slots(env)
    if path is None and env.get("STORYTELLER_CONFIG"):
        path = env["STORYTELLER_CONFIG"]
    data: dict[str, Any] = {}
    source = "<defaults>"
    if path is not None:
        p = Path(path)
        source = str(p)
        data = _read_toml(p, source)
    secret = _find_secret(data, "")
    if secret:
        raise ConfigError(
            source, secret,
            "secrets must not be stored in the config file; put the key in an environment "
            "variable and name that variable with api_key_env",
        )
    unknown = sorted(set(data) - {"llm", "nodes", "trace"})
    if unknown:
        raise ConfigError(source, unknown[0], "unknown section (expected llm, nodes, trace)")
    llm = data.get("llm", {})
    nodes_raw = data.get("nodes", {})
    for name, table in (("llm", llm), ("nodes", nodes_raw)):
        if not isinstance(table, Mapping):
            raise ConfigError(source, name, "expected a table")
    bad_nodes = sorted(set(nodes_raw) - set(NODE_NAMES))
    if bad_nodes:
        raise ConfigError(source, f"nodes.{bad_nodes[0]}", f"unknown node (expected one of {', '.join(NODE_NAMES)})")
    _build_node({}, llm, source, "llm")
    nodes: dict[NodeName, NodeConfig] = {}
    for node in NODE_NAMES:
        table = nodes_raw.get(node, {})
        if not isinstance(table, Mapping):
            raise ConfigError(source, f"nodes.{node}", "expected a table")
        from_file = _build_node(llm, table, source, f"nodes.{node}")
        overrides = _env_overrides(node, env)
        if not overrides:
            nodes[node] = from_file
            continue
        try:
            nodes[node] = _build_node(llm, {**table, **overrides}, "environment", f"nodes.{node}")
        except ConfigError as exc:
            key = (exc.field or "").rsplit(".", 1)[-1]
            var = next(
                (f"STORYTELLER_{node.upper()}_{s}" for s, f in _ENV_FIELDS.items() if f == key),
                "STORYTELLER_MODEL",
            )
            raise ConfigError("environment", var, exc.message) from None
    trace_raw = data.get("trace", {})
    try:
        trace = TraceConfig.model_validate(trace_raw)
    except ValidationError as exc:
        field, msg = _first_error(exc, "trace")
        raise ConfigError(source, field, msg) from None
    return StorytellerConfig(nodes=nodes, trace=trace, source=source)

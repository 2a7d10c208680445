"""``storyteller model ...``: show the resolved per-node LLM config and check the embedded weights."""

from __future__ import annotations

import resource
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from storyteller.orchestrator.cli.options import fail
from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.terminal import say

if TYPE_CHECKING:  # the config module is imported when a command runs, not at CLI start-up
    from storyteller.orchestrator.llm.config import StorytellerConfig

model_app = typer.Typer(help="Inspect and check the LLM configuration and embedded model.", no_args_is_help=True)

ConfigOption = Annotated[Path | None, typer.Option("--config", help="TOML run config (else $STORYTELLER_CONFIG).")]


def register(app: typer.Typer) -> None:
    app.add_typer(model_app, name="model")


def _load(config: Path | None) -> StorytellerConfig:
    from storyteller.orchestrator.llm.config import ConfigError, load_config

    try:
        return load_config(config)
    except ConfigError as exc:
        say(f"error: {plain(exc, keep_newlines=True)}", err=True)
        raise typer.Exit(2) from None


def _local_models(cfg: StorytellerConfig) -> list[str]:
    return sorted({m for n in cfg.nodes.values() for m in n.models if m.startswith("local/")})


@model_app.command("info")
def info(config: ConfigOption = None) -> None:
    """Print each node's model, fallbacks, sampling, timeout and retry settings."""
    from storyteller.orchestrator.llm.model_weights import KNOWN_WEIGHTS, install_command, weights_status

    cfg = _load(config)
    say(f"config: {plain(cfg.source)}   trace fsync: {cfg.trace.fsync}")
    for node_name, node in cfg.nodes.items():
        r = node.retry
        say(plain(
            f"{node_name:13s} model={node.model} fallbacks=[{', '.join(node.fallbacks)}] "
            f"temperature={node.temperature} max_tokens={node.max_tokens} timeout_s={node.timeout_s} "
            f"retry(max_attempts={r.max_attempts}, backoff={r.backoff_base_s}..{r.backoff_max_s}s, "
            f"jitter={r.jitter}, seed={r.seed})"
            + (f" api_base={node.api_base}" if node.api_base else "")
            + (f" api_key_env={node.api_key_env}" if node.api_key_env else "")
        ))  # names from the config file: shown as data
    used = _local_models(cfg)
    for model in used:
        if model.removeprefix("local/") not in KNOWN_WEIGHTS:
            say(f"{plain(model)}: unknown local model")
    say("embedded models:")
    for spec in KNOWN_WEIGHTS.values():
        name = f"local/{spec.model}"
        st = weights_status(spec)
        state = "verified" if st.verified else ("installed, not assembled yet" if st.packages_installed else "MISSING")
        size = f"{spec.size / 1e9:.2f} GB" if spec.size else "size unknown"
        where = "used by this config" if name in used else "not used by this config"
        say(f"  {name}: {spec.description}; {size}, sha256 {spec.sha256[:12]}...; weights {state} "
                   f"({st.assembled_path}); {where}")
        if not st.packages_installed:
            say(f"    install: {install_command(spec)}")
        if name not in used:
            say(f"    use: STORYTELLER_MODEL={name}, or model = \"{name}\" under [llm] in the config")
        if st.problem and name in used:
            say(f"    {st.problem}")
    _echo_local_run_settings()


def _echo_local_run_settings() -> None:
    """The threads a local call would use now (and why) and the progress floors it is held to."""
    from storyteller.orchestrator.llm.cpu_threads import THREADS_ENV, ThreadChooser
    from storyteller.orchestrator.llm.decode_progress import ProgressFloor

    try:
        choice = ThreadChooser().choose()
    except ValueError as exc:
        fail(str(exc))
    say(f"local threads now: {choice.reason()}; chosen again before every call ({THREADS_ENV} fixes them)")
    say(f"local progress floor: {ProgressFloor().describe()}; timeout_s is a hard cap")


@model_app.command("check")
def check(
    config: ConfigOption = None,
    run: Annotated[bool, typer.Option("--run/--no-run", help="Also load each local model and run a tiny JSON call.")] = False,
) -> None:
    """Assemble and sha256-verify the weights of every local model the config uses (exit 1 on failure)."""
    import anyio

    from storyteller.agents.llm_port import ChatMessage, LLMError, LLMRequest
    from storyteller.orchestrator.llm.model_weights import ensure_weights, spec_for

    cfg = _load(config)
    failed = False
    for model in _local_models(cfg):
        t0 = time.perf_counter()
        try:
            path = ensure_weights(spec_for(model))
        except LLMError as exc:
            say(f"{plain(model)}: FAILED: {plain(exc, keep_newlines=True)}", err=True)
            failed = True
            continue
        say(f"{plain(model)}: weights verified ({plain(path)}, {time.perf_counter() - t0:.1f} s)")
        if not run:
            continue
        from storyteller.orchestrator.llm.client import LiteLLMClient
        from storyteller.orchestrator.llm.config import StorytellerConfig

        node = cfg.node("narrator").model_copy(update={"model": model, "fallbacks": ()})
        probe_cfg = StorytellerConfig(nodes={**cfg.nodes, "narrator": node}, source=cfg.source)
        schema = {"type": "object", "properties": {"animal": {"type": "string"}, "legs": {"type": "integer"}},
                  "required": ["animal", "legs"]}
        request = LLMRequest(node="narrator", json_schema=schema, max_tokens=40, messages=(
            ChatMessage(role="user", content="Name an animal and its number of legs, as JSON."),))
        try:
            resp = anyio.run(LiteLLMClient(probe_cfg).complete, request)
        except LLMError as exc:
            say(f"{plain(model)}: call FAILED: {plain(exc, keep_newlines=True)}", err=True)
            failed = True
            continue
        rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        rate = resp.usage.completion_tokens / resp.latency_s if resp.latency_s > 0 else 0.0
        say(f"{plain(model)}: {plain(resp.text)}  ({resp.usage.prompt_tokens}+{resp.usage.completion_tokens} tokens, "
                   f"{resp.latency_s:.1f} s incl. load, {rate:.1f} tok/s, peak RSS {rss_mb:.0f} MB)")
    if failed:
        raise typer.Exit(1)

"""One evaluation on a llama.cpp instance, token by token, held to a progress watch.

:func:`stream_chat` runs a chat completion; :func:`score_continuations` scores a fixed list of
replies from one evaluation of the prompt. Both check, before every prompt batch and every
generated token, the call's :class:`~storyteller.orchestrator.llm.decode_progress.ProgressWatch` (raising
:class:`~storyteller.orchestrator.llm.local_errors.LocalModelStalledError` under its floors) and its cancel
event (raising :class:`_Abort`), then run the caller's ``before_eval`` (the thread re-check of
:mod:`storyteller.orchestrator.llm.local_model`); an exception raised there leaves the model consistent.
Both return an OpenAI-shaped dict. The instance, its lock and its threads are the caller's.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Sequence
from typing import Any

from storyteller.orchestrator.llm.decode_progress import ProgressWatch


class _Abort(Exception):
    """Raised between two evaluations to stop a generation whose caller was cancelled."""


def stream_chat(
    llm: Any, messages: list[dict[str, Any]], params: dict[str, Any], watch: ProgressWatch,
    cancel: threading.Event, before_eval: Callable[[], None] = lambda: None,
) -> dict[str, Any]:
    """Run one chat completion on ``llm``, token by token, held to ``watch``'s floors (raises
    :class:`LocalModelStalledError`) and stopped when ``cancel`` is set (raises
    :class:`_Abort`). Returns an OpenAI-shaped dict.

    llama-cpp-python's ``generate`` evaluates through ``llm.eval``: first the prompt's tokens
    that are not in the KV cache, then one call per generated token. For this call ``eval`` is
    wrapped so the checks, then ``before_eval`` (the thread re-check), run before each prompt
    batch (the same ``n_batch`` batches ``Llama.eval`` makes, so the result is unchanged) and
    before each generated token; an exception raised there leaves the model consistent
    (``n_tokens`` counts what was evaluated).
    Exceptions raised in llama.cpp's own callbacks would be swallowed by ctypes, hence this.
    Usage: completion tokens = streamed content pieces, prompt tokens = tokens in the context
    afterwards minus those."""
    plain_eval = llm.eval
    n_batch = max(1, int(llm.n_batch))

    def check() -> None:
        if cancel.is_set():
            raise _Abort
        watch.check()
        before_eval()

    def watched_eval(tokens: Sequence[int]) -> None:
        if watch.prompt_tokens is None:
            watch.prompt_started(len(tokens))
            for i in range(0, len(tokens), n_batch):
                check()
                plain_eval(tokens[i:i + n_batch])
            watch.prompt_done()
            return
        check()
        plain_eval(tokens)
        watch.decoded(len(tokens))

    pieces: list[str] = []
    finish: str | None = None
    llm.eval = watched_eval
    try:
        stream = llm.create_chat_completion(messages=messages, stream=True, **params)
        try:
            for chunk in stream:
                if cancel.is_set():
                    raise _Abort
                choice = chunk["choices"][0]
                content = choice["delta"].get("content")
                if content:
                    pieces.append(content)
                finish = choice.get("finish_reason") or finish
        finally:
            stream.close()
    finally:
        del llm.eval
    completion_tokens = len(pieces)
    prompt_tokens = max(0, int(llm.n_tokens) - completion_tokens)
    return {
        "id": "local",
        "choices": [{"index": 0, "finish_reason": finish or "stop",
                     "message": {"role": "assistant", "content": "".join(pieces)}}],
        "usage": {"prompt_tokens": prompt_tokens, "completion_tokens": completion_tokens,
                  "total_tokens": prompt_tokens + completion_tokens},
    }


def chat_prompt_tokens(llm: Any, messages: list[dict[str, Any]]) -> tuple[list[int], str]:
    """The tokens of ``messages`` as ``llm``'s chat template lays them out, up to and including
    the assistant's turn opening (what a chat completion would decode after), and the text that
    ends an assistant turn (the template's end-of-sequence token). The template is the model
    file's own (``tokenizer.chat_template``), as llama-cpp-python's chat handler uses it."""
    from llama_cpp.llama_chat_format import Jinja2ChatFormatter

    eos_id = int(llm.token_eos())
    eos = llm.detokenize([eos_id], special=True).decode("utf-8", errors="replace")
    template = str(llm.metadata.get("tokenizer.chat_template", ""))
    if not template:
        raise ValueError("the model file has no chat template to lay out a choice prompt")
    bos_id = int(llm.token_bos())
    bos = llm.detokenize([bos_id], special=True).decode("utf-8", errors="replace") if bos_id >= 0 else ""
    formatted = Jinja2ChatFormatter(template=template, eos_token=eos, bos_token=bos)(messages=messages)  # type: ignore[arg-type]  # OpenAI-shaped dicts, as create_chat_completion takes them
    return list(llm.tokenize(formatted.prompt.encode("utf-8"), add_bos=False, special=True)), eos


def _log_softmax_at(logits: Any, token: int) -> float:
    import numpy as np

    row = np.asarray(logits, dtype=np.float64)
    top = float(row.max())
    return float(row[token] - top - np.log(np.exp(row - top).sum()))


def score_continuations(
    llm: Any, messages: list[dict[str, Any]], choices: Sequence[str], watch: ProgressWatch,
    cancel: threading.Event, before_eval: Callable[[], None] = lambda: None,
) -> dict[str, Any]:
    """The log-likelihood of each of ``choices`` as the whole assistant reply to ``messages``
    (its tokens, then the end of the turn), from one evaluation of the prompt: the prompt's
    tokens are evaluated once (the part already in the KV cache is kept, as a completion does),
    then each choice's tokens one by one from the prompt's end, reading the model's logits.
    Returns an OpenAI-shaped dict whose content is ``{"choice": best, "scores": {choice: ll}}``
    (JSON; ties go to the earlier choice). Held to ``watch`` and ``cancel`` as :func:`stream_chat`."""
    import json

    import numpy as np

    if not choices:
        raise ValueError("no continuations to score")
    n_vocab = int(llm.n_vocab())

    def logits() -> Any:
        return np.ctypeslib.as_array(llm._ctx.get_logits(), shape=(n_vocab,)).copy()

    def step(tokens: Sequence[int]) -> None:
        if cancel.is_set():
            raise _Abort
        watch.check()
        before_eval()
        llm.eval(tokens)

    prompt, end = chat_prompt_tokens(llm, messages)
    cached = int(llm.n_tokens)
    common = min(
        int(llm.longest_token_prefix(llm.input_ids[:cached].tolist(), prompt)), len(prompt) - 1
    )
    llm.n_tokens = common  # what is past the shared prefix is evaluated again (eval drops it from the KV cache)
    watch.prompt_started(len(prompt) - common)
    n_batch = max(1, int(llm.n_batch))
    rest = prompt[common:]
    for i in range(0, len(rest), n_batch):
        step(rest[i:i + n_batch])
    watch.prompt_done()
    after_prompt = logits()
    scores: dict[str, float] = {}
    decoded = 0
    for choice in choices:
        tokens = list(llm.tokenize((choice + end).encode("utf-8"), add_bos=False, special=True))
        llm.n_tokens = len(prompt)
        row, total = after_prompt, 0.0
        for k, token in enumerate(tokens):
            total += _log_softmax_at(row, token)
            if k + 1 < len(tokens):
                step([token])
                watch.decoded(1)
                decoded += 1
                row = logits()
        scores[choice] = total
    llm.n_tokens = len(prompt)
    best = max(choices, key=lambda c: (scores[c], -choices.index(c)))
    content = json.dumps({"choice": best, "scores": {c: round(v, 4) for c, v in scores.items()}})
    return {
        "id": "local",
        "choices": [{"index": 0, "finish_reason": "stop", "message": {"role": "assistant", "content": content}}],
        "usage": {"prompt_tokens": len(prompt), "completion_tokens": decoded,
                  "total_tokens": len(prompt) + decoded},
    }

"""The embedded model's choice among continuations (``storyteller.orchestrator.llm.llama_decoding.score_continuations``)
on a stand-in llama.cpp model whose next-token logits are a fixed function of the last token, so
every candidate's log-likelihood can be computed by hand."""

from __future__ import annotations

import ctypes
import json
import math
import threading
from collections.abc import Sequence
from typing import Any, ClassVar

import numpy as np
import pytest

from storyteller.orchestrator.llm.decode_progress import ProgressWatch
from storyteller.orchestrator.llm.llama_decoding import score_continuations

VOCAB = 128
EOS = 1


def next_logits(last: int) -> np.ndarray:
    """The stand-in's logits after ``last``: the next byte value is likely, EOS after a digit."""
    row = np.zeros(VOCAB, dtype=np.float32)
    row[(last + 1) % VOCAB] = 3.0
    if chr(last).isdigit():
        row[EOS] = 2.0
    return row


class StandInLlama:
    """The parts of ``llama_cpp.Llama`` the scorer uses: bytes are tokens, "\\x01" ends a turn."""

    metadata: ClassVar[dict[str, str]] = {"tokenizer.chat_template": "{% for m in messages %}<{{ m.role }}>{{ m.content }}{% endfor %}<assistant>"}
    n_batch = 8

    def __init__(self) -> None:
        self.n_tokens = 0
        self.input_ids = np.zeros(4096, dtype=np.intc)
        self.evaluated = 0
        self._row = np.zeros(VOCAB, dtype=np.float32)
        self._ctx = self

    def get_logits(self) -> Any:
        return self._row.ctypes.data_as(ctypes.POINTER(ctypes.c_float))

    def n_vocab(self) -> int:
        return VOCAB

    def token_eos(self) -> int:
        return EOS

    def token_bos(self) -> int:
        return -1

    def tokenize(self, text: bytes, add_bos: bool = False, special: bool = False) -> list[int]:
        return list(text)

    def detokenize(self, tokens: Sequence[int], special: bool = False) -> bytes:
        return bytes(tokens)

    @staticmethod
    def longest_token_prefix(a: Sequence[int], b: Sequence[int]) -> int:
        n = 0
        for x, y in zip(a, b, strict=False):
            if x != y:
                break
            n += 1
        return n

    def eval(self, tokens: Sequence[int]) -> None:
        self.input_ids[self.n_tokens : self.n_tokens + len(tokens)] = tokens
        self.n_tokens += len(tokens)
        self.evaluated += len(tokens)
        self._row = next_logits(int(tokens[-1]))


def by_hand(prompt: list[int], continuation: list[int]) -> float:
    total, last = 0.0, prompt[-1]
    for t in continuation:
        row = next_logits(last).astype(np.float64)
        total += float(row[t] - np.log(np.exp(row).sum()))
        last = t
    return total


MESSAGES = [{"role": "system", "content": "pick"}, {"role": "user", "content": "which seat?"}]


def score(llm: StandInLlama, choices: Sequence[str]) -> dict[str, Any]:
    watch = ProgressWatch("local/stand-in", hard_cap_s=600.0)
    out = score_continuations(llm, MESSAGES, choices, watch, threading.Event())
    chosen: dict[str, Any] = json.loads(out["choices"][0]["message"]["content"])
    return chosen


def test_each_choice_is_scored_as_the_whole_reply_and_the_best_is_chosen() -> None:
    llm = StandInLlama()
    choices = ["ab", "a", "c9", "xyz"]
    got = score(llm, choices)
    prompt = list(b"<system>pick<user>which seat?<assistant>")
    for c in choices:
        assert got["scores"][c] == pytest.approx(by_hand(prompt, [*c.encode(), EOS]), abs=1e-3)
    assert got["choice"] == max(choices, key=lambda c: got["scores"][c])
    assert all(math.isfinite(v) for v in got["scores"].values())


def test_the_prompt_is_evaluated_once_and_kept_in_the_cache_for_the_next_call() -> None:
    llm = StandInLlama()
    score(llm, ["ab", "c9"])
    prompt_len = len(b"<system>pick<user>which seat?<assistant>")
    first = llm.evaluated
    assert first == prompt_len + (len("ab") + 1 - 1) + (len("c9") + 1 - 1)  # each choice but its last token
    assert llm.n_tokens == prompt_len  # the candidates' tokens are not left in the context
    score(llm, ["ab", "c9"])
    assert llm.evaluated - first == 1 + 2 + 2  # the prompt's last token again (for its logits), then the choices


def test_a_cancelled_call_stops() -> None:
    from storyteller.orchestrator.llm import llama_decoding

    cancel = threading.Event()
    cancel.set()
    with pytest.raises(llama_decoding._Abort):
        score_continuations(StandInLlama(), MESSAGES, ["a"], ProgressWatch("local/x", hard_cap_s=600.0), cancel)

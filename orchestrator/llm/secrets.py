"""Known secret values, and their removal from any text the LLM boundary keeps or shows.

A provider may echo what it was sent (a 401 body quoting the ``Authorization`` header, a proxy
repeating the request), and an SDK may put the key in an exception message. Every text the
LLM client writes to a trace record, returns as a reply or raises as an error passes through
:func:`redact`, which replaces each known secret value with ``[redacted]``. Known secrets are
the values of the configuration's ``api_key_env`` variables and of every environment variable
whose name says it holds a secret (``KEY``, ``TOKEN``, ``SECRET``, ``PASSWORD``, ...), at least
:data:`MIN_SECRET_CHARS` long (shorter values would redact ordinary words).
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping

MIN_SECRET_CHARS = 8
"""Shortest environment value treated as a secret (characters)."""
REDACTED = "[redacted]"
_SECRET_NAME = re.compile(r"(KEY|TOKEN|SECRET|PASSWORD|PASSWD|CREDENTIAL|AUTH)", re.IGNORECASE)


def secret_values(key_envs: Iterable[str], environ: Mapping[str, str] | None = None) -> tuple[str, ...]:
    """The secret values to redact: the variables named in ``key_envs`` and every variable
    whose name looks secret, longest first (so a key containing another is removed whole)."""
    env = os.environ if environ is None else environ
    names = set(key_envs) | {n for n in env if _SECRET_NAME.search(n)}
    values = {env[n] for n in names if len(env.get(n, "")) >= MIN_SECRET_CHARS}
    return tuple(sorted(values, key=len, reverse=True))


def redact(text: str, secrets: Iterable[str]) -> str:
    """``text`` with every occurrence of each secret replaced by ``[redacted]``."""
    for secret in secrets:
        if secret in text:
            text = text.replace(secret, REDACTED)
    return text

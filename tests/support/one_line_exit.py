"""The check every bad-input test shares: the command exited with code 2 after printing one
non-empty line on stderr (holding the given words), and no traceback."""

from __future__ import annotations

from typer.testing import Result


def one_line_exit_2(result: Result, *needles: str) -> str:
    """The one stderr line of a command that refused its input with exit code 2."""
    assert result.exit_code == 2, (result.exit_code, result.output)
    assert result.exception is None or isinstance(result.exception, SystemExit), repr(result.exception)
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and "Traceback" not in result.output, result.stderr
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]

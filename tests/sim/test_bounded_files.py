"""``storyteller.sim.bounded_files``: a file read back costs at most its cap, and bad JSON is one line.

Each case is an input the plain ``Path.read_bytes`` / ``json.loads`` pair mishandles: reading
``/dev/zero`` never ends, a FIFO blocks, deep nesting is a ``RecursionError``, 5,000 digits a
``ValueError`` from the interpreter's int limit, ``1e400`` silently becomes infinity.
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from storyteller.sim.bounded_files import (
    MAX_INT_DIGITS,
    MAX_OBJECT_KEYS,
    MAX_TOML_KEY_PARTS,
    BoundedFileError,
    json_depth_exceeds,
    json_keys_exceed,
    load_bounded_json,
    load_bounded_toml,
    read_bounded_bytes,
    toml_key_parts,
)


def one_line(exc: pytest.ExceptionInfo[BoundedFileError], *needles: str) -> str:
    text = str(exc.value)
    assert "\n" not in text
    for needle in needles:
        assert needle in text, text
    return text


def test_a_small_file_is_read_whole(tmp_path: Path) -> None:
    path = tmp_path / "a.json"
    path.write_bytes(b"x" * 100)
    assert read_bounded_bytes(path, 100, str(path)) == b"x" * 100


def test_a_file_over_its_cap_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "a.json"
    path.write_bytes(b"x" * 101)
    with pytest.raises(BoundedFileError) as exc:
        read_bounded_bytes(path, 100, "the run file")
    one_line(exc, "the run file", "100")


def test_dev_zero_is_refused_not_read_forever() -> None:
    with pytest.raises(BoundedFileError) as exc:
        read_bounded_bytes("/dev/zero", 1 << 20, "run.json")
    one_line(exc, "run.json", "not a regular file")


def test_a_fifo_without_a_writer_does_not_block(tmp_path: Path) -> None:
    fifo = tmp_path / "story.json"
    os.mkfifo(fifo)
    with pytest.raises(BoundedFileError) as exc:
        read_bounded_bytes(fifo, 1 << 20, str(fifo))
    one_line(exc, "not a regular file")


def test_missing_file_and_folder(tmp_path: Path) -> None:
    with pytest.raises(BoundedFileError) as exc:
        read_bounded_bytes(tmp_path / "nope", 10, "nope")
    one_line(exc, "not found")
    with pytest.raises(BoundedFileError) as exc:
        read_bounded_bytes(tmp_path, 10, "folder")
    one_line(exc, "folder")


def test_a_symlink_is_refused_when_asked(tmp_path: Path) -> None:
    target = tmp_path / "secret"
    target.write_bytes(b"secret")
    link = tmp_path / "link"
    link.symlink_to(target)
    assert read_bounded_bytes(link, 10, "link") == b"secret"
    with pytest.raises(BoundedFileError) as exc:
        read_bounded_bytes(link, 10, "link", follow_symlinks=False)
    one_line(exc, "symbolic link")


def test_json_is_parsed() -> None:
    assert load_bounded_json(b'\xef\xbb\xbf{"a": [1, -2.5, "]]]{{"], "b": null}', 2, "f") == {
        "a": [1, -2.5, "]]]{{"],
        "b": None,
    }
    assert load_bounded_json('{"a": 1}', 1, "f") == {"a": 1}


@pytest.mark.parametrize(
    ("data", "needle"),
    [
        (b"[" * 100_000 + b"]" * 100_000, "nested more than 64 levels"),
        (b'{"a": ' * 70 + b"1" + b"}" * 70, "nested more than 64 levels"),
        (b"[" * 100_000, "nested more than 64 levels"),  # not even valid: still no RecursionError
        (b'{"time": ' + b"9" * 5000 + b"}", "5000 digits"),
        (b'{"time": ' + b"9" * 400 + b".0}", "too large"),
        (b"[1e400]", "too large"),
        (b'{"a": NaN}', "non-finite"),
        (b"[-Infinity]", "non-finite"),
        (b'{"a": 1', "not valid JSON"),
        (b"\xff\xfe{}", "not UTF-8"),
    ],
)
def test_bad_json_is_one_line(data: bytes, needle: str) -> None:
    with pytest.raises(BoundedFileError) as exc:
        load_bounded_json(data, 64, "run.json")
    one_line(exc, "run.json", needle)


def test_depth_counts_brackets_outside_strings_only() -> None:
    assert not json_depth_exceeds(b'[["[[[[[[[[", "\\"[[[["]]', 2)
    assert json_depth_exceeds(b"[[[]]]", 2)
    assert not json_depth_exceeds(b"[[]][[]][[]]", 2)
    # a quote followed by many escaped quotes (a quadratic trap for a naive string pattern)
    assert not json_depth_exceeds(b'"' + b'\\"' * 200_000, 2)


def test_integers_up_to_the_limit_are_kept() -> None:
    big = "9" * MAX_INT_DIGITS
    assert load_bounded_json(f"[{big}, -{big}]", 2, "f") == [int(big), -int(big)]


def test_an_object_of_too_many_keys_is_refused() -> None:
    """Found by the hostile corpus: a story.json step of 1.2 million unknown keys took 1.2 GB and
    ran past 8 s in the model's validation (one error built per key)."""

    def keys(n: int) -> bytes:
        return ("{" + ",".join(f'"k{i}":0' for i in range(n)) + "}").encode()

    assert len(load_bounded_json(keys(MAX_OBJECT_KEYS), 4, "x")) == MAX_OBJECT_KEYS
    with pytest.raises(BoundedFileError) as info:
        load_bounded_json(keys(MAX_OBJECT_KEYS + 1), 4, "story.json")
    one_line(info, "story.json", "keys")


def test_keys_are_counted_outside_strings_only() -> None:
    text = b'{"a": "' + b":" * 50 + b'", "b": {"c": 1}}'
    assert not json_keys_exceed(text, 3)
    assert json_keys_exceed(text, 2)


def test_toml_key_parts_are_counted_outside_strings_and_comments() -> None:
    """Found by the second hostile corpus: tomllib's time is quadratic in a dotted key's parts
    (a key of 50,000 parts: 1.5 GB, killed), so keys are counted before it parses."""
    assert toml_key_parts('[llm.retry]\nmodel = "a.b.c.d.e.f" # x.y.z.w\nbase = \'1.2.3.4\'\n') == 2
    assert toml_key_parts('a.b."c.d".e = 1\n') == 4  # a quoted part is one part
    assert toml_key_parts('x = "q\\"a.b.c.d"\ny = 1.5\n') == 2  # an escaped quote stays in its string
    assert toml_key_parts("x = \'\'\'\na.b.c.d.e\n\'\'\'\n") == 1
    assert toml_key_parts('"' * 100_000 + "'" * 100_000 + "#" * 10) == 1  # strings that never close: linear
    assert load_bounded_toml(b"[a.b.c]\nd.e = 1\n", "f.toml") == {"a": {"b": {"c": {"d": {"e": 1}}}}}
    with pytest.raises(BoundedFileError) as info:
        load_bounded_toml(("x." * MAX_TOML_KEY_PARTS + "y = 1\n").encode(), "deep.toml")
    one_line(info, "deep.toml", f"{MAX_TOML_KEY_PARTS + 1} dotted parts")

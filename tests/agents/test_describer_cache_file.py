"""A cached scene description is read within bounds: a good file is a hit; a huge, deeply nested,
non-regular or malformed one is a miss (the scene is described again), never a crash or a hang."""

from __future__ import annotations

import os
from pathlib import Path

from storyteller.agents.describer import MAX_CACHE_BYTES, read_cached, write_cached
from storyteller.agents.messages import SceneDescription

GOOD = SceneDescription(scene="flat", text="- kitchen (eat): chair_1, table_1", source="describer", attempts=1)


def test_a_written_description_reads_back(tmp_path: Path) -> None:
    path = tmp_path / "flat.json"
    write_cached(path, GOOD)
    assert read_cached(path) == GOOD


def test_a_hostile_cache_file_is_a_miss(tmp_path: Path) -> None:
    huge = tmp_path / "huge.json"
    huge.write_bytes(b'{"scene": "flat", "text": "' + b"x" * (MAX_CACHE_BYTES + 10) + b'"}')
    deep = tmp_path / "deep.json"
    deep.write_text("[" * 100_000 + "]" * 100_000, encoding="utf-8")
    fifo = tmp_path / "fifo.json"
    os.mkfifo(fifo)  # opening it to read would block forever
    wrong = tmp_path / "wrong.json"
    wrong.write_text('{"scene": 3}', encoding="utf-8")
    for path in (huge, deep, fifo, wrong, tmp_path / "absent.json", tmp_path):
        assert read_cached(path) is None, path.name

"""Moved to ``benchmark.support.fake_openai_server`` (the speed scripts use it and must not
import ``tests``). This name stays only for ``tests/test_run_folder_links.py``, which another
engineer is changing at the time of the move; import from ``benchmark.support`` instead, and
delete this file once that test does."""

from benchmark.support.fake_openai_server import FakeOpenAI

__all__ = ["FakeOpenAI"]

"""Moved to ``benchmark.support.headless_chromium`` (the speed scripts use it and must not
import ``tests``). This name stays only for ``tests/test_viewer_access.py``, which another
engineer is changing at the time of the move; import from ``benchmark.support`` instead, and
delete this file once that test does."""

from benchmark.support.headless_chromium import Chromium, chromium_binary

__all__ = ["Chromium", "chromium_binary"]

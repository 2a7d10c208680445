"""Planning-quality evaluation (reference cases, scoring, expressions) and performance scripts
that print ratios against a baseline measured in the same run.

The top floor: may import everything below, never ``tests``; the fakes and frozen oracles the
speed scripts compare against are in ``benchmark/support`` (the tests use them from there too).
No product package imports from here.
"""

"""Planning-quality evaluation (reference cases, scoring, expressions) and performance scripts
that print ratios against a baseline measured in the same run.

The top floor: may import everything below, and ``tests.support`` for the frozen oracles the
speed scripts compare against. Nothing imports from here.
"""

"""Fakes and frozen baselines that the speed scripts time against, shared with the tests.

- ``crowd_walkers``: walkers between random targets, and the crowd measure read off their tracks;
- ``fake_openai_server``: a scripted OpenAI-compatible server on 127.0.0.1 (no network);
- ``headless_chromium``: a headless Chromium driven over the DevTools protocol;
- ``motion_reference``: the motion step as it was before its speed-ups (frozen oracle);
- ``picture_reference``: the top-down picture drawn with matplotlib (frozen oracle);
- ``random_tracks``: a deterministic wandering story (tracks only, no planning);
- ``scene_graph_reference``: the brute-force scene graph and clusters (frozen oracle).

On the benchmark floor: may import ``sim``, ``tools``, ``agents`` and ``orchestrator``, never
``tests``. The tests import these modules from here; none is used by the product at run time.
"""

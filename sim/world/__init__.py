"""The world step: characters, story events and their phases, cooperative walking and motion,
one frame at a time, and the per-frame tracks the exporters read.

``step`` (World, WorldConfig, the frame) drives ``event_book`` (events, start queue, who is
free), ``arrivals`` (walkers arriving, stopping short or stuck) and ``frame_assembly`` (motion queries in, poses and track rows out); ``events`` holds
the planner's commands and the step's reports, ``phases`` a character's state, ``navigation``
the world's view of the cooperative planner; ``tracks`` the per-frame output in memory and
``track_chunks`` the same output streamed to append-only chunk files (one per character, a torn
last record detected), so a long story holds one window of frames. May import ``storyteller.sim.scene``, ``storyteller.sim.paths``,
``storyteller.sim.motion`` and ``storyteller.sim.body``; nothing above ``sim``.

Deterministic: the same commands at the same frames give the same tracks.
"""

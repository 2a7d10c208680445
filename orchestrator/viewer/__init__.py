"""The story viewer behind ``storyteller view``: a run folder shown in the browser.

What lives here:

- :mod:`.run_folder` reads a run folder (``story.json``, ``scene.json`` or the bundled scene
  it names, ``<name>.track.npz``; for a run still in progress ``story.jsonl`` and the motion
  chunk files) into a :class:`~.run_folder.RunData`, and stamps the folder so a viewer can
  notice a run that is still being written; :mod:`.live_run` reads such a run again at each
  change from what its files gained (a full read when one was cut or replaced);
- :mod:`.timeline` answers, per frame, which story events are on and what each character does
  (pure functions of the run data);
- :mod:`.figures` poses the stand-in figure (the GLB export's box body) as the 22 bones of a
  skinned mesh, frame by frame (pure numpy);
- :mod:`.scene_view` puts a run into a ``viser`` scene (boxes, paths, figures, labels) and
  shows one frame; with ``--smplx-model`` the figures are the characters' SMPL-X bodies, computed
  by :mod:`storyteller.orchestrator.bodies` (``smplx`` and ``torch`` load only then); :mod:`.server` adds the timeline and event-list controls and serves it;
  :mod:`.export` records the whole story into one self-contained HTML file;
- :mod:`.access` decides which requests the server answers (its own pages; with a token when it
  listens beyond this machine), :mod:`.inbound` which websocket messages reach viser (binary
  viser messages that decode, GUI updates viser can apply), and :mod:`.guarded_server` applies
  both to viser's server.

May import ``sim`` and the rest of ``orchestrator``; ``viser`` only inside :mod:`.scene_view`,
:mod:`.server`, :mod:`.panels`, :mod:`.guarded_server`, :mod:`.inbound` and :mod:`.export`, which the command
imports lazily.

Guarantees: the viewer only reads the run folder, except for the instructions typed in its box
and the presses of its run panel (:mod:`.panels`), which it appends to ``viewer_instructions.jsonl``
and ``viewer_controls.jsonl`` there (never through a link:
``storyteller.orchestrator.session.viewer_instructions``); every frame it
shows is a frame of the exported tracks (no resampling); the server listens on 127.0.0.1
unless ``--host`` says otherwise, answers no page of another site and no request naming another
host (and, beyond 127.0.0.1, none without its token), never opens viser's share tunnel, and
needs no network (the browser client is the one built into the ``viser`` wheel); a websocket
message that is not what the page sends closes that connection, never the server, and leaves
no traceback in the log.
"""

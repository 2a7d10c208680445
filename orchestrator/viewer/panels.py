"""The director's panels of the viewer: the run's pause and speed, the planner, the characters, the story.

- **Run**: the simulation now, from the run's ``live.json`` (``storyteller.orchestrator.session.live_state``,
  polled every :data:`LIVE_POLL_S`): its frame, pace and speed, paused or not; *Pause the run* /
  *Resume the run* and *Run speed* append a line to ``viewer_controls.jsonl``
  (``storyteller.orchestrator.session.viewer_controls``), which the run applies at a frame boundary. Refused,
  with the reason under them: a run that is not realtime (``live.json`` says why), has ended, has
  not started, or cannot be written to. The viewer's own Play / Pause and speed (the timeline) only
  move what this page shows.
- **Planner**: per role (describer, narrator, event parser, the unified planner) whether it is
  thinking and for how long, its calls, and its last reply with the seconds it took.
- **Characters**: a button per character. A click selects it in that browser only (a marker over
  its head), and the camera of that browser follows it from where it looks now; a second click
  lets go. Under the buttons, that browser's selected character: its event, action and place in
  the run now (``live.json``), its action and events at the frame shown, and its events so far.
- **Story**: the story so far as ``story.md`` tells it
  (``storyteller.orchestrator.session.run_report.story_markdown`` of the events the page has), growing as
  events start and end.

All text from the run folder (replies, activities, places, names) is data: it reaches the
markdown through :func:`storyteller.orchestrator.safe_text.markdown` (every markdown and HTML character
escaped) and labels through :func:`storyteller.orchestrator.safe_text.plain`.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, cast

import numpy as np
import viser

from storyteller.orchestrator.safe_text import markdown
from storyteller.orchestrator.session.live_state import LiveState, read_live_bytes, read_live_state
from storyteller.orchestrator.session.run_manifest import ManifestError, read_manifest
from storyteller.orchestrator.session.run_report import story_markdown
from storyteller.orchestrator.session.viewer_controls import CONTROLS_FILE, ControlKind, send_control
from storyteller.orchestrator.viewer.run_folder import STORY_FILE, RunData
from storyteller.orchestrator.viewer.timeline import action_at, active_events, clock, event_line

LIVE_POLL_S = 0.25
"""Wall seconds between two looks at ``live.json``."""
RUN_SPEEDS = ("0.25", "0.5", "1", "2", "4")
PICK_WAIT_S = 10.0
"""Seconds a picked speed stays in the dropdown before the run's own speed is shown again."""
STALE_S = 5.0
"""Wall seconds without a new ``live.json`` after which a running run is said to be silent."""
REPLY_LINES = 12
"""Lines of a role's last reply shown."""
ROLE_NAMES = {"event_parser": "event parser", "planner": "planner (unified)"}
MARKER_ABOVE_PELVIS = 1.35  # metres: over the head and its label


class ControlRefused(Exception):
    """A press the run panel does not send (the message is the reason it shows)."""


def _lines(text: str, limit: int = REPLY_LINES) -> str:
    """``text`` escaped line by line, as markdown lines (at most ``limit``)."""
    rows = [markdown(r) for r in text.splitlines() if r.strip()]
    more = len(rows) > limit
    rows = rows[:limit] + (["\u2026"] if more else [])
    return "  \n".join(rows)


def run_line(live: LiveState | None, *, now_unix: float, ended: bool) -> str:
    """The run panel's status: the simulated frame, pace and speed, and whether it is paused."""
    if live is None:
        return "**Run**: the run has written no live state yet" + (" (it has ended)" if ended else "")
    at = f"sim frame {live.frame} ({clock(live.frame, live.fps)}) of {live.frames}"
    pace = f"{markdown(live.pace)}, speed {live.speed:g}\u00d7"
    if not live.running or ended:
        return f"**Run**: ended at {at}"
    if live.paused:
        state = f"**paused** at frame {live.frame}"
    elif live.pausing:
        state = "pausing at the next frame"
    else:
        state = "running"
    silent = now_unix - live.updated_unix
    quiet = f" (not heard from for {silent:.0f} s)" if silent > STALE_S else ""
    return f"**Run**: {at} \u00b7 {pace} \u00b7 {state}{quiet}"


def planner_text(live: LiveState | None) -> str:
    """The planner panel: per role, thinking or idle, calls, the last reply."""
    if live is None or not live.roles:
        return "No planner call yet."
    parts = []
    for r in live.roles:
        name = markdown(ROLE_NAMES.get(r.role, r.role))
        doing = f"thinking for {r.thinking_s:.1f} s" if r.thinking_s is not None else "idle"
        failed = f", {r.failed} failed" if r.failed else ""
        head = f"**{name}**: {doing} \u00b7 {r.calls} calls{failed}"
        if r.last_reply:
            took = f" ({r.last_reply_s:.1f} s)" if r.last_reply_s is not None else ""
            head += f"  \nlast reply{took}:  \n{_lines(r.last_reply)}"
        parts.append(head)
    return "\n\n".join(parts)


def character_text(name: str, run: RunData, frame: int, live: LiveState | None) -> str:
    """The selected character's panel: now in the run, at the frame shown, its events so far."""
    lines = [f"**{markdown(name)}**"]
    row = next((c for c in live.characters if c.name == name), None) if live is not None else None
    if row is not None and live is not None:
        what = f"in the run now (sim frame {live.frame}): {markdown(row.state)}"
        if row.event_id:
            what += f", event {markdown(row.event_id)}: {markdown(row.activity)}"
        lines.append(what)
        lines.append(f"action: {markdown(row.action) or 'none'} \u00b7 place: {markdown(row.place) or 'none'}")
    track = next((t for t in run.tracks if t.name == name), None)
    last = run.num_frames - 1
    mine = [e for e in run.events if name in e.characters]
    if track is not None:
        action = action_at(track, frame)
        on = [run.events[i] for i in active_events(run.events, frame, last) if name in run.events[i].characters]
        shown = f"at the frame shown ({clock(frame, run.fps)}): {markdown(action) or 'no action'}"
        if on:
            shown += f", in {markdown(on[-1].event_id)}"
        lines.append(shown)
    lines.append(f"events so far: {len(mine)}")
    lines += [f"- {markdown(event_line(e, run.fps).strip())}" for e in mine[-20:]]
    return "  \n".join(lines[:4]) + ("\n\n" + "\n".join(lines[4:]) if len(lines) > 4 else "")


def story_panel_text(run: RunData, frames: int) -> str:
    """The story so far as ``story.md`` tells it, every text escaped for the panel."""
    story: dict[str, Any] = {
        "scene": run.scene.name if run.scene is not None else "",
        "characters": [t.name for t in run.tracks],
        "instruction": run.instruction,
        "fps": run.fps,
        "frames": frames,
        "steps": [],
        "events": [e.model_dump(mode="json") for e in run.events],
    }
    return story_markdown(story, text=markdown)


class DirectorPanels:
    """The panels of one viewer (see the module doc); ``lock`` is the viewer's. Run and Planner
    go at ``order`` in the panel, Characters and Story at ``later``."""

    def __init__(self, server: viser.ViserServer, folder: Path, lock: threading.RLock, *, order: float,
                 later: float) -> None:
        self.server = server
        self.folder = folder
        self.lock = lock
        self.run: RunData | None = None
        self.frame = 0
        self.live: LiveState | None = None
        self._live_raw: bytes | None = None
        self._stop = threading.Event()
        self._selected: dict[int, str] = {}  # client id -> character
        self._client_text: dict[int, viser.GuiMarkdownHandle] = {}
        self._markers: dict[int, Any] = {}
        self._buttons: list[viser.GuiButtonHandle] = []
        gui = server.gui
        with gui.add_folder("Run (simulation)", order=order):
            self.run_status = gui.add_markdown("**Run**: waiting for the run to start")
            self.pause = gui.add_button("Pause the run")
            self.speed = gui.add_dropdown("Run speed", RUN_SPEEDS, initial_value="1")
            self._shown_speed = "1"  # the speed this viewer last put in the dropdown (from live.json)
            self._picked_at: float | None = None  # monotonic time a person's pick was sent
            self.note = gui.add_markdown("")
        with gui.add_folder("Planner", order=order + 0.1):
            self.planner = gui.add_markdown("No planner call yet.")
        self.characters_folder = gui.add_folder("Characters", order=later)
        self._characters_order = later + 0.05
        with gui.add_folder("Story", order=later + 0.1):
            self.story = gui.add_markdown("")
        self.pause.on_click(lambda _: self._press_pause())
        self.speed.on_update(self._on_speed)
        server.on_client_connect(self._add_client)
        server.on_client_disconnect(self._drop_client)

    # ----- lifecycle -----------------------------------------------------------------------
    def start(self) -> None:
        self.poll_live()
        threading.Thread(target=self._live_loop, name="viewer-live-state", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()

    def _live_loop(self) -> None:
        while not self._stop.wait(LIVE_POLL_S):
            self.poll_live()

    # ----- what the viewer shows -----------------------------------------------------------
    def show_run(self, run: RunData) -> None:
        """A run (re)loaded: the character buttons and the story."""
        with self.lock:
            self.run = run
            names = [t.name for t in run.tracks]
            if [b.label for b in self._buttons] != names:
                for button in self._buttons:
                    button.remove()
                self._buttons = []
                with self.characters_folder:
                    for name in names:
                        button = self.server.gui.add_button(name)
                        button.on_click(self._selector(name))
                        self._buttons.append(button)
            self._show_story()
            self._refresh_clients()

    def show_frame(self, frame: int) -> None:
        """The frame shown changed: follow the selected characters, refresh their panels."""
        with self.lock:
            self.frame = frame
            self._follow()
            self._refresh_clients()

    def poll_live(self) -> None:
        """Read ``live.json`` when it changed and show it."""
        try:  # within live.json's cap: a planted 3 GB file was read whole on every poll
            raw = read_live_bytes(self.folder)
        except ValueError as exc:
            raw = str(exc).encode()  # changed: read_live_state below says what is wrong
        ended = (self.folder / STORY_FILE).exists()
        with self.lock:
            if raw is not None and raw != self._live_raw:
                self._live_raw = raw
                try:
                    self.live = read_live_state(self.folder)
                except ValueError as exc:
                    self.note.content = markdown(exc)
                self._show_live()
                self._show_story()
                self._refresh_clients()
            content = run_line(self.live, now_unix=time.time(), ended=ended)
            if self.run_status.content != content:
                self.run_status.content = content

    def _show_live(self) -> None:
        live = self.live
        if live is None:
            return
        label = "Resume the run" if live.pausing or live.paused else "Pause the run"
        if self.pause.label != label:
            self.pause.label = label
        refused = live.controls is not None or not live.running
        self.pause.disabled = refused
        self.speed.disabled = refused
        speed = f"{live.speed:g}"
        if speed not in self.speed.options:
            self.speed.options = tuple(sorted({*self.speed.options, speed}, key=float))
        if self.speed.value == speed:
            self._shown_speed, self._picked_at = speed, None
        elif not self._pick_pending():
            cast(Any, self.speed).value = speed  # viser declares the setter on a subclass mypy does not see
            self._shown_speed, self._picked_at = speed, None
        if live.controls is not None:
            self.note.content = f"**Pause and speed refused:** {markdown(live.controls)}"
        elif not live.running:
            self.note.content = "The run has ended: it takes no more pause or speed."
        text = planner_text(live)
        if self.planner.content != text:
            self.planner.content = text

    def _show_story(self) -> None:
        if self.run is None:
            return
        frames = max(self.run.num_frames, self.live.frame if self.live is not None else 0)
        text = story_panel_text(self.run, frames)
        if self.story.content != text:
            self.story.content = text

    # ----- the run's controls ------------------------------------------------------------
    def _press_pause(self) -> None:
        with self.lock:
            live = self.live
        kind: ControlKind = "resume" if live is not None and (live.pausing or live.paused) else "pause"
        self._send(kind)

    def _pick_pending(self) -> bool:
        """A person picked a speed the run has not applied yet: the live poll leaves the dropdown
        alone (it once put the old speed back between viser storing the pick and :meth:`_on_speed`
        reading it, and the pick was never sent) until :data:`PICK_WAIT_S` after it was sent."""
        if self.speed.value == self._shown_speed:
            return False
        return self._picked_at is None or time.monotonic() - self._picked_at < PICK_WAIT_S

    def _on_speed(self, event: viser.GuiEvent[viser.GuiDropdownHandle[str]]) -> None:
        if event.client is None:  # our own update from live.json
            return
        with self.lock:
            live, picked = self.live, self.speed.value
            if live is not None and f"{live.speed:g}" == picked:
                return
            self._picked_at = time.monotonic()
        self._send("speed", float(picked))

    def _send(self, kind: ControlKind, speed: float | None = None) -> None:
        try:
            self.send_control(kind, speed)
        except ControlRefused as exc:
            self.note.content = f"**Not sent:** {markdown(exc)}"
            return
        what = f"speed {speed:g}" if speed is not None else kind
        self.note.content = f"Sent: {markdown(what)} (the run applies it at its next frame)"

    def send_control(self, kind: ControlKind, speed: float | None = None) -> None:
        """Append a press to the run's control file; :class:`ControlRefused` says why not."""
        with self.lock:
            live = self.live
        if (self.folder / STORY_FILE).exists() or (live is not None and not live.running):
            raise ControlRefused("the run has ended")
        if live is not None and live.controls is not None:
            raise ControlRefused(live.controls)
        try:
            thread = read_manifest(self.folder).thread_id
        except ManifestError:
            raise ControlRefused("the run has not started yet (no run.json in its folder)") from None
        try:
            send_control(self.folder, thread, kind, speed, sent_unix=time.time())
        except ValueError as exc:
            raise ControlRefused(str(exc)) from None
        except OSError as exc:
            raise ControlRefused(f"cannot write {exc.filename or CONTROLS_FILE} ({exc.strerror or exc})") from None

    # ----- characters, per browser ---------------------------------------------------------
    def _add_client(self, client: viser.ClientHandle) -> None:
        text = client.gui.add_markdown("Click a character to follow it.", order=self._characters_order)
        with self.lock:
            self._client_text[client.client_id] = text

    def _drop_client(self, client: viser.ClientHandle) -> None:
        with self.lock:
            self._client_text.pop(client.client_id, None)
            self._selected.pop(client.client_id, None)
            self._markers.pop(client.client_id, None)

    def _selector(self, name: str) -> Callable[[viser.GuiEvent[viser.GuiButtonHandle]], None]:
        return lambda event: self.select(event.client, name)

    def select(self, client: viser.ClientHandle | None, name: str) -> None:
        """``client`` selects ``name`` (again: lets it go): a marker over it, the camera follows."""
        if client is None:
            return
        with self.lock:
            cid = client.client_id
            if self._selected.get(cid) == name:
                del self._selected[cid]
                marker = self._markers.pop(cid, None)
                if marker is not None:
                    marker.remove()
            else:
                self._selected[cid] = name
                if cid not in self._markers:
                    self._markers[cid] = client.scene.add_icosphere(
                        "/selected", radius=0.1, color=(255, 215, 0), cast_shadow=False)
                self._follow(only=cid)
            self._refresh_clients(only=cid)

    def _root(self, name: str) -> np.ndarray | None:
        """Where ``name``'s pelvis is at the frame shown (None: not in the run)."""
        run = self.run
        track = next((t for t in run.tracks if t.name == name), None) if run is not None else None
        if track is None or track.num_frames == 0:
            return None
        i = min(max(self.frame, 0), track.num_frames - 1)
        return np.asarray(track.root_positions[i], dtype=float)

    def _follow(self, only: int | None = None) -> None:
        clients = self.server.get_clients()
        for cid, name in list(self._selected.items()):
            if only is not None and cid != only:
                continue
            client = clients.get(cid)
            target = self._root(name)
            if client is None or target is None:
                continue
            marker = self._markers.get(cid)
            if marker is not None:
                marker.position = target + np.array([0.0, 0.0, MARKER_ABOVE_PELVIS])
            cam = client.camera
            offset = np.asarray(cam.position) - np.asarray(cam.look_at)
            if not np.all(np.isfinite(offset)) or np.linalg.norm(offset) < 0.5:
                offset = np.array([0.0, -3.0, 2.5])
            with client.atomic():
                cam.look_at = target
                cam.position = target + offset

    def _refresh_clients(self, only: int | None = None) -> None:
        run = self.run
        for cid, text in list(self._client_text.items()):
            if only is not None and cid != only:
                continue
            name = self._selected.get(cid)
            if name is None or run is None:
                content = "Click a character to follow it." if run is not None else ""
            else:
                content = character_text(name, run, self.frame, self.live)
            if text.content != content:
                text.content = content

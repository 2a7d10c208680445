"""The interactive viewer: a :class:`~.scene_view.SceneView` plus timeline and event list.

Controls (the panel of the ``viser`` client): Play / Pause, a speed choice, a frame slider
(scrub), the clock, and the story's events as buttons, one per event, in story order; the
events on at the current frame are coloured, and clicking one jumps to its start frame.
Text from the run folder (its name, the instruction, activities, error messages) is data: the
panel's markdown gets it through :func:`storyteller.orchestrator.safe_text.markdown` (viser renders raw HTML
in markdown), buttons and labels through :func:`storyteller.orchestrator.safe_text.plain`.

The instruction box ("Direct the story", one per browser: what one person types is not in
another's box): Send (or Enter) appends the text to the run folder's
``viewer_instructions.jsonl`` (:mod:`storyteller.orchestrator.session.viewer_instructions`), on disk before
the page says "Sent"; the run takes it as its latest instruction at its next frame, as a line
typed on its stdin (source ``viewer``). Refused, with the reason under the box: an empty text,
one over ``MAX_INSTRUCTION_CHARS``, one holding a lone surrogate (not text: a client that is not a
browser can send one), a run that has ended (``story.json`` is there) or has not
started (no ``run.json``). A run that was killed keeps what was sent meanwhile: its ``resume``
takes it. The text is shown escaped, as everything from the run folder.

The director's panels (:mod:`.panels`): the run's pause, resume and speed (a realtime run's
``viewer_controls.jsonl``, :mod:`storyteller.orchestrator.session.viewer_controls`), its frame and the
planner's roles from ``live.json`` (:mod:`storyteller.orchestrator.session.live_state`), a character list
whose click selects a figure and has that browser's camera follow it, and the story so far.

Who may connect: the pages this viewer served, checked on every request
(:mod:`.access`, applied by :mod:`.guarded_server`); on a host beyond loopback only with the
token of :attr:`ViewerApp.url`. viser's share button (a public tunnel) is hidden and refused.

Playback runs on a thread of this process: it advances the frame by ``speed * fps`` per wall
second and stops at the last frame. A second thread polls the run folder
(:func:`~.run_folder.folder_stamp`) and reloads the run when a file it shows changes.

Live: a run still in progress is shown as soon as it has written its story stream and first
chunk records (:func:`~.run_folder.is_ready`; until then the panel says it is waiting). Each
time the chunk files or the story stream grow, what they gained is read (:mod:`.live_run`: the
appended records only, the whole file again when one was cut or replaced), the new frames are added to the scene
(:meth:`~.scene_view.SceneView.extend`), the slider and clock reach further and the event list
gets the new events and states; playing at the last frame of a live run waits there and goes
on as frames arrive (it follows the run). When the run ends it writes ``story.json`` and its
exports, and the viewer shows them. A folder that stops being readable keeps the last good
run on screen and says why in the panel.
"""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import structlog
import viser

from storyteller.orchestrator.bodies.smplx_meshes import SmplxBody, SmplxModelError, SmplxModels, run_bodies
from storyteller.orchestrator.safe_text import markdown, plain
from storyteller.orchestrator.session.run_manifest import ManifestError, read_manifest
from storyteller.orchestrator.session.viewer_instructions import (
    INBOX_FILE,
    ViewerInstruction,
    instruction_problem,
    send_instruction,
)
from storyteller.orchestrator.viewer.access import TOKEN_PARAM, ViewerAccess, authority
from storyteller.orchestrator.viewer.guarded_server import guarded_server
from storyteller.orchestrator.viewer.live_run import RunReader
from storyteller.orchestrator.viewer.panels import DirectorPanels
from storyteller.orchestrator.viewer.run_folder import (
    STORY_FILE,
    RunData,
    RunFolderError,
    folder_stamp,
    is_ready,
)
from storyteller.orchestrator.viewer.scene_view import SceneView
from storyteller.orchestrator.viewer.timeline import active_events, clock, event_line

_log = structlog.get_logger("storyteller.viewer")


class InstructionRefused(Exception):
    """An instruction the box does not send (the message is the reason the page shows)."""


HOST = "127.0.0.1"  # the default: this machine only
SPEEDS = ("0.25", "0.5", "1", "2", "4")
TICK_S = 1 / 30  # wall seconds between playback steps
POLL_S = 1.0  # wall seconds between checks of the run folder


class ViewerApp:
    """Serve one run folder; :meth:`start` returns once the server listens."""

    def __init__(
        self,
        folder: Path,
        *,
        port: int = 8080,
        host: str = HOST,
        autoplay: bool = False,
        smplx_model: Path | None = None,
    ) -> None:
        self.folder = folder
        self.models = SmplxModels(smplx_model) if smplx_model is not None else None
        self.access = ViewerAccess.for_host(host)
        self.server = guarded_server(self.access, port=port, label="storyteller", verbose=False)
        self.lock = threading.RLock()
        self.view: SceneView | None = None
        self.run: RunData | None = None
        self.frame = 0
        self.position = 0.0  # fractional frame while playing
        self.playing = autoplay
        self._stamp: tuple[tuple[str, int, int], ...] | None = None
        self.reader = RunReader(folder)
        """Reads the run at each change: a live run's appended records only (:mod:`.live_run`)."""
        self._stop = threading.Event()
        self._event_buttons: list[viser.GuiButtonHandle] = []
        self._active: list[int] = []
        gui = self.server.gui
        gui.configure_theme(control_width="large", show_share_button=False)
        self.status = gui.add_markdown(f"**{markdown(folder.name)}**")
        with gui.add_folder("Timeline"):
            self.play = gui.add_button("Pause" if autoplay else "Play", icon=None)
            self.speed = gui.add_dropdown("Speed", SPEEDS, initial_value="1")
            self.slider = gui.add_slider("Frame", min=0, max=1, step=1, initial_value=0)
            self.clock = gui.add_markdown("")
        self.events_folder = gui.add_folder("Events")
        self.play.on_click(lambda _: self.toggle())
        self.slider.on_update(self._on_slider)
        self._box_order = self.status.order + 0.5  # each browser's instruction box: under the status line
        self.server.on_client_connect(self._add_instruction_box)
        self.panels = DirectorPanels(self.server, folder, self.lock, order=self._box_order + 0.1,
                                     later=self.events_folder.order + 1)

    # ----- lifecycle -----------------------------------------------------------------
    @property
    def url(self) -> str:
        """Where to open the viewer; with the token when it listens beyond this machine (a
        wildcard bind is shown under this machine's host name)."""
        host = socket.gethostname() if self.access.wildcard else self.access.host
        base = f"http://{authority(host, self.server.get_port())}"
        return base if self.access.token is None else f"{base}/?{TOKEN_PARAM}={self.access.token}"

    def reach(self, what: str) -> str:
        """The line(s) to print once the server listens: ``what`` (e.g. the run folder) at
        :attr:`url`, and beyond this machine who can connect and that the token is the key."""
        if self.access.token is None:
            return f"viewing {plain(what)} at {self.url} (this machine only; Ctrl-C to stop)"
        where = "every address of this machine" if self.access.wildcard else plain(self.access.host)
        return (
            f"viewing {plain(what)} at {self.url} (Ctrl-C to stop)\n"
            f"  listening on {where}, port {self.server.get_port()}: any machine that can reach it there can "
            "connect, and only with this URL's token sees the run and controls the viewer; keep the URL private"
        )

    def start(self) -> None:
        """Load the run (or wait for it) and start the playback and folder-watch threads."""
        self.reload_if_changed()
        self.panels.start()
        threading.Thread(target=self._play_loop, name="viewer-play", daemon=True).start()
        threading.Thread(target=self._watch_loop, name="viewer-watch", daemon=True).start()

    def stop(self) -> None:
        self._stop.set()
        self.panels.stop()
        self.server.stop()

    # ----- loading -------------------------------------------------------------------
    def reload_if_changed(self) -> bool:
        """Reload the run when its files changed since the last look; True when it did."""
        stamp = folder_stamp(self.folder)
        if stamp == self._stamp:
            return False
        self._stamp = stamp
        if not is_ready(self.folder):
            self.status.content = f"**{markdown(self.folder.name)}**: waiting for the run to write its outputs..."
            return False
        try:
            run = self.reader.load()
            if self.reader.reread is not None:
                _log.info("viewer.reread", folder=str(self.folder), reason=self.reader.reread)
            bodies = self._bodies(run) if self.models is not None else None
        except (RunFolderError, SmplxModelError) as exc:
            self.status.content = f"**{markdown(self.folder.name)}**: {markdown(exc)}"
            return False
        if run.live and not run.tracks:  # the story stream is there, no whole chunk record yet
            self.status.content = f"**{markdown(self.folder.name)}**: waiting for the run's first frames..."
            return False
        self._show_run(run, bodies)
        return True

    def _bodies(self, run: RunData) -> dict[str, SmplxBody]:
        """SMPL-X bodies: from the run's ``.smplx.npz`` exports, or from the streamed tracks while
        it runs (the exports do not exist yet)."""
        assert self.models is not None
        if not run.live:
            return run_bodies(self.folder, [t.name for t in run.tracks], self.models)
        from storyteller.sim.export.smplx_npz import smplx_parameters

        return {t.name: self.models.body(smplx_parameters(t)) for t in run.tracks}

    def _show_run(self, run: RunData, bodies: Mapping[str, SmplxBody] | None = None) -> None:
        with self.lock:
            if self.view is None or bodies is not None or not self.view.extend(run):
                self.server.scene.reset()
                self.view = SceneView(self.server, run, bodies=bodies)
            self.run = run
            length = clock(run.num_frames - 1, run.fps)
            what = f"live, {length} so far (the run is still going)" if run.live else length
            lines = [f"**{markdown(self.folder.name)}**: {len(run.tracks)} characters, {what}"]
            if run.instruction:
                lines.append(f"*{markdown(run.instruction)}*")
            if run.scene_note:
                lines.append(markdown(run.scene_note))
            self.status.content = "\n\n".join(lines)
            self._list_events(run)
            for button in self._event_buttons:  # goto() colours the events on at the frame
                button.color = None
            self._active = []
            self.slider.max = max(run.num_frames - 1, 1)
            self.panels.show_run(run)
            self.goto(min(self.frame, run.num_frames - 1))

    def _list_events(self, run: RunData) -> None:
        """One button per event: relabel the ones there, add the new ones, drop the rest."""
        lines = [event_line(event, run.fps) for event in run.events]
        for button, line in zip(self._event_buttons, lines, strict=False):
            if button.label != line:
                button.label = line
        for button in self._event_buttons[len(lines) :]:
            button.remove()
        del self._event_buttons[len(lines) :]
        with self.events_folder:
            for i in range(len(self._event_buttons), len(lines)):
                button = self.server.gui.add_button(lines[i])
                button.on_click(self._jumper(i))
                self._event_buttons.append(button)

    # ----- the instruction box ---------------------------------------------------------
    def _add_instruction_box(self, client: viser.ClientHandle) -> None:
        """One box per browser (what one person types is not shown in another's box): a text
        field and Send (or Enter), and a line saying what became of the last one sent."""
        with client.gui.add_form("Direct the story", order=self._box_order) as form:
            text = client.gui.add_text("Instruction", "", hint="What should happen next (the story's latest instruction).")
            send = client.gui.add_button("Send")
            note = client.gui.add_markdown("")
        send.on_click(lambda _: form.submit())
        form.on_submit(lambda _: self._send(text, note))

    def _send(self, text: viser.GuiTextHandle, note: viser.GuiMarkdownHandle) -> None:
        typed = text.value
        try:
            line = self.send_instruction(typed)
        except InstructionRefused as exc:
            note.content = f"**Not sent:** {markdown(exc)}"
            return
        text.value = ""  # type: ignore[misc]  # viser declares the setter on a subclass mypy does not see
        note.content = f"Sent: *{markdown(line.text)}* (the run takes it at its next frame)"

    def send_instruction(self, typed: str) -> ViewerInstruction:
        """Append ``typed`` to the run folder's instruction file for the running story;
        :class:`InstructionRefused` says why not (empty, too long, the run has ended or not
        started, the file cannot be written)."""
        problem = instruction_problem(typed)
        if problem is not None:
            raise InstructionRefused(problem)
        if not typed.isprintable() and any(0xD800 <= ord(c) <= 0xDFFF for c in typed):  # a client, not a browser
            raise InstructionRefused("the instruction holds a lone surrogate: not text (send it as UTF-8)")
        with self.lock:
            run = self.run
        if (self.folder / STORY_FILE).exists() or (run is not None and not run.live):
            raise InstructionRefused("the run has ended: a finished story takes no more instructions")
        try:
            thread = read_manifest(self.folder).thread_id
        except ManifestError:
            raise InstructionRefused("the run has not started yet (no run.json in its folder)") from None
        try:
            return send_instruction(self.folder, thread, typed, sent_unix=time.time())
        except OSError as exc:
            raise InstructionRefused(f"cannot write {exc.filename or INBOX_FILE} ({exc.strerror or exc})") from None

    # ----- controls ------------------------------------------------------------------
    def toggle(self) -> None:
        with self.lock:
            if self.run is None:
                return
            if not self.playing and self.frame >= self.run.num_frames - 1 and not self.run.live:
                self.goto(0)  # play again from the start (a live run: go on as frames arrive)
            self.playing = not self.playing
            self.position = float(self.frame)
            self.play.label = "Pause" if self.playing else "Play"

    def jump_to_event(self, index: int) -> None:
        with self.lock:
            if self.run is not None and index < len(self.run.events):
                self.goto(self.run.events[index].applied_frame)

    def _jumper(self, index: int) -> Callable[[viser.GuiEvent[viser.GuiButtonHandle]], None]:
        return lambda _: self.jump_to_event(index)

    def _on_slider(self, event: viser.GuiEvent[viser.GuiSliderHandle[int]]) -> None:
        if event.client is not None:  # moved in a browser (our own updates come with no client)
            self.goto(int(self.slider.value))

    def goto(self, frame: int) -> None:
        """Show ``frame`` (clamped to the run) in the scene, the slider, clock and event list."""
        with self.lock:
            if self.run is None or self.view is None:
                return
            last = self.run.num_frames - 1
            self.frame = min(max(int(frame), 0), last)
            self.position = float(self.frame)
            self.view.show(self.frame)
            self.slider.value = self.frame  # type: ignore[misc]  # viser declares the setter on a subclass mypy does not see
            self.clock.content = f"{clock(self.frame, self.run.fps)} / {clock(last, self.run.fps)}"
            active = active_events(self.run.events, self.frame, last)
            if active != self._active:
                for i, button in enumerate(self._event_buttons):
                    button.color = "green" if i in active else None
                self._active = active
            self.panels.show_frame(self.frame)

    # ----- threads -------------------------------------------------------------------
    def advance(self, dt: float) -> None:
        """One playback step: ``dt`` wall seconds later. At the last frame playing stops, except
        in a live run, which waits there and goes on when frames arrive (it follows the run)."""
        with self.lock:
            if not self.playing or self.run is None:
                return
            end = self.run.num_frames - 1
            self.position = min(self.position + float(self.speed.value) * dt * self.run.fps, end)
            position = self.position
            if int(position) != self.frame:
                self.goto(int(position))
                self.position = position  # goto() snaps it to the frame
            if position >= end and not self.run.live:
                self.playing = False
                self.play.label = "Play"

    def _play_loop(self) -> None:
        last = time.monotonic()
        while not self._stop.wait(TICK_S):
            now = time.monotonic()
            dt, last = now - last, now
            self.advance(dt)

    def _watch_loop(self) -> None:
        while not self._stop.wait(POLL_S):
            self.reload_if_changed()

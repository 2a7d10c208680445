"""The live view of ``storyteller run`` on a terminal: a ``rich.live.Live`` display of a run's
:class:`~storyteller.orchestrator.session.run_status.RunStatus`.

What it shows (:func:`live_view`): the simulated clock against the story's length, the speed
(simulated seconds per wall second) and the pace; one row per character (state, current event
and what it is, action label, place); per LLM role the calls in flight and for how long the
oldest has run, the calls so far, the failed ones and the tokens of the answers; the events
by state, the planning steps and the latest instruction; with ``--interactive`` on the same
terminal, the instruction being typed on its last line (``storyteller.orchestrator.session.terminal_prompt``
takes the echo from the terminal, which would otherwise be drawn over). The story's lines
(``[  10.6s] event-0000 starts: ...``) are printed above the display (:meth:`LiveView.line`),
once each, so they stay in the terminal's scroll-back as the plain output would.

Text is data: every name, activity, place and instruction goes into a ``rich.text.Text``
(never parsed as markup) after :func:`storyteller.orchestrator.safe_text.plain` (no control character
reaches the terminal), so ``[bold red]x[/]`` or ``[link=...]`` show literally.

Cheap on the event loop: the display refreshes only from :meth:`LiveView.running`'s task
every ``period_s`` (no refresh thread reads the world while a frame is stepped), and one
refresh builds two small tables. On stop the last state stays on screen (``transient=False``).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator, Callable
from dataclasses import dataclass
from typing import TextIO

from rich.console import Console, Group, RenderableType
from rich.live import Live
from rich.text import Text

from storyteller.orchestrator.safe_text import plain
from storyteller.orchestrator.session.run_report import clock
from storyteller.orchestrator.session.run_status import CharacterActivity, RunSnapshot, RunStatus
from storyteller.orchestrator.terminal import escaped, say

REFRESH_PERIOD_S = 0.25
"""Wall seconds between two refreshes of the display (4 a second)."""

_STATE_STYLE: dict[CharacterActivity, str] = {
    "idle": "dim",
    "seated": "dim",
    "waiting": "yellow",
    "walking": "cyan",
    "starting": "green",
    "acting": "bold green",
    "finishing": "green",
}


def _data(text: object, style: str = "") -> Text:
    """Text from a user, a model or a program: shown literally, never as markup."""
    return Text(plain(text), style=style)


def _seconds(value: float) -> str:
    return f"{value:.1f} s"


def _header(s: RunSnapshot) -> Text:
    if not s.started:
        return Text("starting: loading the scene, the motion and the model", style="dim")
    done = 100.0 * s.frame / s.frames if s.frames else 100.0
    speed = f"x{s.speed:.2f}" if s.speed is not None else "x-"
    return Text.assemble(
        (f"{clock(s.frame, s.fps)} / {clock(s.frames, s.fps)}", "bold cyan"), f" ({done:.0f}%)  ",
        ("speed ", "dim"), speed, (" sim s/wall s", "dim"), "  ",
        ("wall ", "dim"), _seconds(s.wall_s), "  ",
        ("pace ", "dim"), plain(s.pace),
        no_wrap=True, overflow="ellipsis",
    )


@dataclass(frozen=True)
class _Column:
    """A column of :func:`_grid`: ``width`` cells, or 0 to take its cells' width out of what is left."""

    header: str
    width: int = 0
    right: bool = False


def _fit(natural: list[int], room: int) -> list[int]:
    """Widths for columns that want ``natural`` cells in ``room``: the narrow ones whole, the
    room left shared evenly by the wide ones (at least 6 cells each)."""
    widths = list(natural)
    order = sorted(range(len(natural)), key=lambda i: natural[i])
    for k, i in enumerate(order):
        share = max(6, room // (len(order) - k))
        widths[i] = min(natural[i], share)
        room -= widths[i]
    return widths


def _grid(columns: list[_Column], rows: list[list[Text]], width: int) -> list[Text]:
    """A header, a rule and one line per row: each cell cut to its column (with an ellipsis)
    and padded. Lines, not a ``rich.table.Table``: a table measures every cell on every
    refresh, several times slower for a few dozen rows."""
    gap = 2
    flexible = [i for i, c in enumerate(columns) if not c.width]
    natural = [max([len(columns[i].header), *(row[i].cell_len for row in rows)]) for i in flexible]
    room = width - sum(c.width for c in columns) - gap * (len(columns) - 1)
    widths = [c.width for c in columns]
    for i, w in zip(flexible, _fit(natural, room), strict=True):
        widths[i] = w

    def line(cells: list[Text], style: str = "") -> Text:
        out = Text(style=style, no_wrap=True, overflow="crop")
        for i, (cell, w) in enumerate(zip(cells, widths, strict=True)):
            cell = cell.copy()
            cell.truncate(w, overflow="ellipsis")
            pad = " " * (w - cell.cell_len)
            if i:
                out.append(" " * gap)
            if columns[i].right:
                out.append(pad)
                out.append_text(cell)
            else:
                out.append_text(cell)
                out.append(pad)
        return out

    head = line([Text(c.header) for c in columns], "bold")
    rule = Text("\u2500" * min(width, sum(widths) + gap * (len(columns) - 1)), style="dim")
    return [head, rule, *(line(cells) for cells in rows)]


def _characters(s: RunSnapshot, width: int) -> list[Text]:
    name_w = max([9, *(len(c.name) for c in s.characters)])
    action_w = max([6, *(len(c.action) for c in s.characters)])
    columns = [_Column("character", min(16, name_w)), _Column("state", 9), _Column("event", 10),
               _Column("activity"), _Column("action", min(22, action_w)), _Column("place")]
    rows = [[_data(c.name, "bold"), Text(c.state, style=_STATE_STYLE[c.state]), _data(c.event_id),
             _data(c.activity), _data(c.action), _data(c.place)] for c in s.characters]
    return _grid(columns, rows, width)


def _calls(s: RunSnapshot, width: int) -> list[Text]:
    columns = [_Column("LLM role", 12), _Column("in flight", 9, right=True), _Column("for", 7, right=True),
               _Column("calls", 5, right=True), _Column("failed", 6, right=True),
               _Column("prompt tok", 10, right=True), _Column("completion tok", 14, right=True)]  # 75 cells
    rows = []
    for r in s.roles:
        busy = "bold yellow" if r.in_flight else "dim"
        rows.append([_data(r.role), Text(str(r.in_flight), style=busy),
                     Text(_seconds(r.longest_s) if r.in_flight else "-", style=busy), Text(str(r.calls)),
                     Text(str(r.failed), style="red" if r.failed else ""),
                     Text(f"{r.prompt_tokens:,}"), Text(f"{r.completion_tokens:,}")])
    if len(s.roles) != 1:
        rows.append([Text("all" if s.roles else "no call yet", style="dim"), Text(str(s.in_flight)), Text(""),
                     Text(str(s.calls)), Text(str(sum(r.failed for r in s.roles))),
                     Text(f"{s.prompt_tokens:,}"), Text(f"{s.completion_tokens:,}")])
    return _grid(columns, rows, width)


def _footer(s: RunSnapshot) -> list[Text]:
    failed = s.count("failed")
    lines = [Text.assemble(
        ("events ", "dim"), f"{s.count('ongoing') + s.count('looping')} under way, ",
        (f"{s.count('completed')} done", "green"), ", ", (f"{failed} failed", "red" if failed else ""),
        ("  planning steps ", "dim"), str(s.steps),
    )]
    if s.instruction:
        lines.append(Text.assemble(("instruction ", "dim"), _data(s.instruction), no_wrap=True, overflow="ellipsis"))
    return lines


def _prompt(typed: str, width: int) -> Text:
    """The instruction being typed (its end, when it is longer than the line), or a hint."""
    head = "instruction> "
    if not typed:
        return Text.assemble((head, "bold"), ("type a new instruction, Enter gives it", "dim"), no_wrap=True)
    room = max(8, width - len(head) - 2)
    shown = Text(plain(typed))
    if shown.cell_len > room:
        shown = Text("\u2026" + plain(typed)[-(room - 1):])
    return Text.assemble((head, "bold"), shown, ("\u2588", "dim"), no_wrap=True, overflow="crop")


def live_view(s: RunSnapshot, width: int = 120, typed: str | None = None) -> RenderableType:
    """The display of one snapshot, ``width`` cells wide; ``typed``: the instruction being
    typed below it (None: instructions are not typed here)."""
    lines = [_header(s), Text("")]
    if s.characters:
        lines += [*_characters(s, width), Text("")]
    lines += [*_calls(s, width), Text(""), *_footer(s)]
    if typed is not None:
        lines.append(_prompt(typed, width))
    return Group(*lines)


class LiveView:
    """A ``rich.live.Live`` display of ``status`` on ``console`` (see the module doc).

    ``redirect_stderr``: lines written to ``sys.stderr`` while it runs (log lines) are printed
    above the display instead of through it; right when stderr is the same terminal.
    ``typed``: the instruction being typed so far (``orchestrator.session.terminal_prompt``),
    drawn on the display's last line; None when instructions are not typed here."""

    def __init__(self, status: RunStatus, console: Console, *, period_s: float = REFRESH_PERIOD_S,
                 redirect_stderr: bool = False, typed: Callable[[], str] | None = None) -> None:
        self.status = status
        self.console = console
        self.period_s = period_s
        self.typed = typed
        self.live = Live(console=console, auto_refresh=False, transient=False, redirect_stdout=True,
                         redirect_stderr=redirect_stderr)
        self._loop: asyncio.AbstractEventLoop | None = None

    def refresh(self) -> None:
        typed = self.typed() if self.typed is not None else None
        self.live.update(escaped(live_view(self.status.snapshot(), self.console.width, typed)), refresh=True)

    def refresh_soon(self) -> None:
        """Refresh on the event loop as soon as it can (safe from any thread: a key typed)."""
        loop = self._loop
        if loop is not None:
            with contextlib.suppress(RuntimeError):  # the loop closed meanwhile
                loop.call_soon_threadsafe(self._refresh_if_running)

    def _refresh_if_running(self) -> None:
        if self._loop is not None:
            self.refresh()

    def line(self, text: str) -> None:
        """A line of the story (``plain`` text) above the display, as the plain output prints it."""
        say(Text(plain(text)), console=self.live.console, soft_wrap=True)

    async def _refreshing(self) -> None:
        while True:
            self.refresh()
            await asyncio.sleep(self.period_s)

    @contextlib.asynccontextmanager
    async def running(self) -> AsyncIterator[RunStatus]:
        """The display on screen while the body runs (refreshed by a task on the running event
        loop); stopped with its last state kept (without the prompt line) when the body ends or raises."""
        self.live.start()
        self._loop = asyncio.get_running_loop()
        task = asyncio.ensure_future(self._refreshing())
        try:
            yield self.status
        finally:
            self._loop = None
            self.typed = None  # nothing is read any more: the last state without the prompt line
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
            try:
                self.refresh()
            finally:
                self.live.stop()


def terminal_view(stream: TextIO, *, stderr_is_terminal: bool, typed: Callable[[], str] | None = None) -> LiveView:
    """A live view on ``stream`` (stdout), drawn as on a terminal even when it is not one (an
    explicit ``--live``)."""
    return LiveView(RunStatus(), Console(file=stream, force_terminal=True), redirect_stderr=stderr_is_terminal,
                    typed=typed)

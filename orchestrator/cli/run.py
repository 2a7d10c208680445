"""``storyteller run``: plan and animate a story in a scene (the main job); ``storyteller
resume RUN_DIR`` (go on after a stop, from ``run.json`` and ``session.snapshot``) and
``storyteller replay RUN_DIR|TRACE --out DIR`` (the same run with no model loaded). All three
take ``--smplx-model DIR`` (the GLB export with SMPL-X body meshes).

The job is :mod:`storyteller.orchestrator.session.run_job`: the simulation and the planner run
concurrently (``storyteller.orchestrator.session.runtime``). Outputs, all in ``--out``: ``story.json``
(events with their frames and per-character plans), ``story.md`` (the same as text),
``metrics.json`` (LLM use per role, simulation speed, frame intervals), ``run.json`` (thread
id and arguments), ``session.snapshot`` (last checkpoint), ``trace.jsonl`` (every LLM call,
replayable), ``runs.sqlite`` (planning checkpoints and story log), ``scene.json`` (the scene as run), per character
``<name>.smplx.npz`` / ``.bvh`` / ``.track.npz``, ``scene.glb`` (whole scene, skinned and
animated), ``topdown.png`` and the animation: with ``--video``, ``story.mp4`` (or ``story.gif`` when
imageio-ffmpeg is not installed); with ``--gif``, ``story.gif``.

``--replay T.jsonl`` serves every LLM call from a recorded trace and applies each planning
result at the frame recorded there: the same arguments reproduce the same events and the same
motion, with no model loaded.

Live instructions: the narrator always sees the latest instruction (a new one replaces the
old). ``--instructions FILE`` is a timed script (``00:30 Ben leaves the kitchen``, simulated
time; see ``storyteller.orchestrator.session.instruction_script``); with ``--interactive`` (the default
when stdin is a terminal) every line typed while the story runs becomes the instruction at
the next frame, and so does every line sent from the instruction box of a viewer of the run
folder (``--view``, or ``storyteller view OUT`` elsewhere: ``storyteller.orchestrator.session.viewer_instructions``).
The trace records each one with its frame, and a replay applies it there. A script line at or
after the end of the run (``--duration``) would never take effect: ``run`` says so in one
``warning:`` line on stderr before the story starts, and goes on (a short preview of a long
script stays possible).

``--view [--port P] [--host H]`` (``run`` and ``resume``): the browser viewer of ``--out``
(``storyteller view OUT --play``) is started in a child process before the first frame
(``storyteller.orchestrator.viewer.child``: its Python work stays off the run's frames), its address is
printed (with a token when ``--host`` is not this machine), and it goes on serving after the
story ends until Ctrl-C (SIGINT or SIGTERM; the exit code is the run's). A stop signal while
the story runs stops both, as without ``--view``; a run killed outright takes its viewer along
within a second.

``--planner unified|direct`` and ``--description object-list|scene-graph`` plan with the
paper's ablations (variants of the planning graph, ``storyteller.orchestrator.planning.ablation_graph``),
driven by the same step planner.

Output: a line per event as it starts, completes or fails, saying what its applied plan has
the characters do (``[   10.6s] event-0000 starts: Ava makes coffee at the coffee maker.``,
``storyteller.agents.story_text``) and per instruction, then a summary line. On a terminal (``--live``, the default
when stdout is a terminal) a live view (``storyteller.orchestrator.cli.live_view``) shows below those
lines: simulated time and speed, each character's state and event, LLM calls in flight,
tokens so far; with ``--interactive`` on the same terminal its last line is the instruction
being typed (``storyteller.orchestrator.session.terminal_prompt``).

Exit codes: 0 the story ran to its end; 1 planning stopped (the error is printed) or a write
failed (``error: cannot write FILE: ...``, a full disk: what was written before stays readable
and ``resume`` goes on once there is space); 2 a user error (bad argument, damaged run folder,
one line naming the file); 130 / 143 (128 + the signal) stopped by SIGINT / SIGTERM: the run
stops at a frame boundary, writes the story so far, its motion and its checkpoint at that
frame, says so in one line, and ``storyteller resume`` goes on from there.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, NoReturn

import typer

from storyteller.orchestrator.cli.options import (
    Characters,
    Config,
    Description,
    InProcessPrograms,
    Instruction,
    LiveOption,
    MaxRetries,
    PaceOption,
    Planner,
    ProgramGrammar,
    SceneArg,
    ViewHostOption,
    ViewOption,
    ViewPortOption,
    fail,
)
from storyteller.orchestrator.safe_text import one_line, plain
from storyteller.orchestrator.terminal import say
from storyteller.sim.run_folder_names import RUNS_DB, TRACE_JSONL

if TYPE_CHECKING:  # the session (simulation, planner) is imported by the command itself
    from storyteller.orchestrator.sandbox_worker import WorkerRunner
    from storyteller.orchestrator.session.instruction_script import ScriptLine
    from storyteller.orchestrator.session.run_manifest import RunArguments, RunManifest
    from storyteller.orchestrator.session.session_types import StoryEvent
    from storyteller.orchestrator.session.terminal_prompt import TerminalPrompt
    from storyteller.orchestrator.viewer.child import ViewerProcess
    from storyteller.sim.scene.model import Scene


SmplxModelOption = Annotated[
    Path | None,
    typer.Option(
        "--smplx-model",
        help="Folder with the SMPL-X model files (SMPLX_NEUTRAL.npz ...): the GLB carries SMPL-X body meshes "
        "instead of stand-in figures.",
    ),
]


def register(app: typer.Typer) -> None:
    app.command("run")(run_command)
    app.command("resume")(resume_command)
    app.command("replay")(replay_command)


def _event_line(e: StoryEvent, fps: int) -> str:
    t = (e.finished_frame if e.finished_frame is not None else e.applied_frame) / fps
    what = {"ongoing": "starts", "looping": "loops", "completed": "done", "failed": "failed"}[e.state]
    return f"[{t:7.1f}s] {plain(e.event_id)} {what}: {plain(e.text or ', '.join(e.characters))}"


def run_command(
    scene: SceneArg,
    characters: Characters = 2,
    names: Annotated[str | None, typer.Option("--names", help="Character names, comma-separated (sets their number; overrides -n).")] = None,
    instruction: Instruction = "",
    instructions: Annotated[Path | None, typer.Option("--instructions", help="Timed script of instructions: lines 'MM:SS text' in simulated time ('#' comments).")] = None,
    interactive: Annotated[bool | None, typer.Option("--interactive/--no-interactive", help="Lines typed on stdin become the instruction while the story runs (default: when stdin is a terminal; under the live view the line being typed shows on its last line).")] = None,
    live: LiveOption = None,
    duration: Annotated[float, typer.Option("--duration", "-d", min=1.0, help="Simulated seconds.")] = 60.0,
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder.")] = Path("out"),
    pace: PaceOption = "lockstep",
    speed: Annotated[float, typer.Option("--speed", help="Simulated seconds per wall second (realtime pace).")] = 1.0,
    planners: Annotated[int | None, typer.Option("--planners", min=1, max=8, help="Planning steps in flight at most, for disjoint characters (default: 1 in lockstep pace, 2 otherwise).")] = None,
    offline_latency: Annotated[float | None, typer.Option("--offline-latency", min=0.0, help="offline pace: simulated seconds each LLM call takes (default: the call's own latency).")] = None,
    max_events: Annotated[int | None, typer.Option("--max-events", min=1, help="Planning steps at most; a step that comes back as a wait does not count.")] = None,
    record: Annotated[Path | None, typer.Option("--record", help="Trace file (default: OUT/trace.jsonl).")] = None,
    replay: Annotated[Path | None, typer.Option("--replay", help="Serve LLM calls and frames from this trace.")] = None,
    config: Config = None,
    motion_config: Annotated[Path | None, typer.Option("--motion-config", help="TOML mapping mocap clips to actions.")] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of start positions, sampling and paths.")] = 0,
    max_retries: MaxRetries = 3,
    program_grammar: ProgramGrammar = True,
    in_process_programs: InProcessPrograms = False,
    video: Annotated[bool, typer.Option("--video/--no-video", help="Also write an animated top-down story.mp4 (story.gif when imageio-ffmpeg is missing).")] = False,
    gif: Annotated[bool, typer.Option("--gif/--no-gif", help="Also write an animated top-down story.gif.")] = False,
    foot_ik: Annotated[bool, typer.Option("--foot-ik/--raw-feet", help="Leg IK on the synthesized motion: feet pinned while planted and kept out of furniture (--raw-feet: the matched poses as they are).")] = True,
    thread_id: Annotated[str | None, typer.Option("--thread-id", help="Planning thread id (default: a new one; see run.json).")] = None,
    planner: Planner = "event",
    description: Description = "describer",
    smplx_model: SmplxModelOption = None,
    view: ViewOption = False,
    port: ViewPortOption = 8080,
    host: ViewHostOption = "127.0.0.1",
) -> None:
    """Plan and animate a story; write motion, pictures, the story log and the trace."""
    from storyteller.orchestrator.session.instruction_script import MAX_INSTRUCTION_CHARS
    from storyteller.orchestrator.session.roster import character_names
    from storyteller.orchestrator.session.run_manifest import RunArguments, absolute, parse_names

    if len(instruction) > MAX_INSTRUCTION_CHARS:
        fail(f"--instruction: {len(instruction)} characters, at most {MAX_INSTRUCTION_CHARS} allowed")
    if not math.isfinite(duration):  # run.json holds finite numbers only: resume and replay refuse others
        fail(f"--duration must be a finite number of seconds, got {duration}")
    if offline_latency is not None and not math.isfinite(offline_latency):
        fail(f"--offline-latency must be a finite number of seconds, got {offline_latency}")
    try:
        cast = parse_names(names) if names is not None else tuple(character_names(characters))
    except ValueError as exc:
        fail(str(exc))
    if len(cast) > 24:
        fail(f"--names: at most 24 characters, got {len(cast)}")
    if replay is not None and not replay.is_file():
        fail(f"{replay}: trace file not found")
    _check_smplx_model(smplx_model)
    script: tuple[ScriptLine, ...] = ()
    if instructions is not None:
        from storyteller.orchestrator.session.instruction_script import (
            InstructionScriptError,
            read_instruction_script,
        )

        try:
            script = read_instruction_script(instructions)
        except InstructionScriptError as exc:
            fail(str(exc))
        if replay is None:
            warn_unreached(script, duration, str(instructions))
    scene_path = Path(scene)
    from pydantic import ValidationError

    from storyteller.sim.validation_text import user_error

    try:
        args = RunArguments(
            scene=absolute(scene_path) or scene if scene_path.is_file() else scene,
            names=cast,
            instruction=instruction,
            instructions=script,
            duration=duration,
            pace=pace,
            speed=speed,
            planners=planners if planners is not None else default_planners(pace),
            offline_latency=offline_latency,
            max_events=max_events,
            config=absolute(config),
            motion_config=absolute(motion_config),
            seed=seed,
            max_retries=max_retries,
            program_grammar=program_grammar,
            foot_ik=foot_ik,
            planner=planner,
            description=description,
            video=video,
            gif=gif,
        )
    except ValidationError as exc:  # what run.json could not hold, or resume and view could not read back
        fail(user_error("the run's arguments", exc))
    trace_path = record if record is not None else (None if replay is not None else out / TRACE_JSONL)
    if trace_path is not None and replay is not None and trace_path.resolve() == replay.resolve():
        fail("--record must name a different file than --replay")
    shown, typing = live_and_interactive(live, interactive, reads_stdin=replay is None)
    _execute(args, out=out, trace_path=trace_path, replay=replay, thread_id=thread_id, resume=False,
             interactive=typing, live=shown, smplx_model=smplx_model, in_process_programs=in_process_programs,
             view=ViewAt(port, host) if view else None)


def warn_unreached(script: tuple[ScriptLine, ...], duration: float, source: str) -> None:
    """Say (one ``warning:`` line on stderr) when script lines fall at or after the run's last
    frame: the run goes on, and those instructions never take effect."""
    from storyteller.sim.world.step import WorldConfig

    fps = WorldConfig().fps
    frames = round(duration * fps)
    late = [line for line in script if round(line.time_s * fps) >= frames]  # as the session schedules them
    if late:
        say(
            f"warning: {plain(source)}: {len(late)} instruction(s) at or after {duration:g} s, the end of the run "
            f"(--duration), never take effect (the first: {late[0].time_s:g} s {plain(late[0].text[:60])!r})",
            err=True,
        )


def _check_smplx_model(smplx_model: Path | None) -> None:
    """Refuse a ``--smplx-model`` folder without the neutral model file before anything runs."""
    if smplx_model is None:
        return
    from storyteller.orchestrator.bodies.smplx_meshes import SmplxModelError, model_file

    try:
        model_file(smplx_model, "neutral")
    except SmplxModelError as exc:
        fail(str(exc))


def default_planners(pace: str) -> int:
    """Steps in flight at most without ``--planners``: one in lockstep pace (the story of a
    lockstep run stays what it always was), two otherwise (narrate the next event while the
    current one is parsed)."""
    return 1 if pace == "lockstep" else 2


def live_and_interactive(live: bool | None, interactive: bool | None, *, reads_stdin: bool) -> tuple[bool, bool]:
    """(show the live view?, read instructions typed on stdin?) from ``--live/--no-live`` and
    ``--interactive/--no-interactive`` (None: not given): the live view by default when stdout
    is a terminal, typing when stdin is one (both on one terminal: the typed line is drawn in
    the live view, see :func:`_typing_prompt`). ``reads_stdin``: False in a replay (stdin is
    never read)."""
    import sys

    typing = reads_stdin and (interactive if interactive is not None else sys.stdin.isatty())
    shown = live if live is not None else sys.stdout.isatty()
    return shown, typing


def _typing_prompt(live: bool, interactive: bool) -> TerminalPrompt | None:
    """The prompt that reads typed instructions key by key and lets the live view draw them,
    when both are on and stdin is a terminal (its echo would be drawn over); None otherwise
    (the plain line reader: no live view, or stdin is not a terminal and echoes nothing)."""
    import sys

    if not (live and interactive and sys.stdin.isatty()):
        return None
    from storyteller.orchestrator.session.terminal_prompt import TerminalPrompt

    return TerminalPrompt(sys.stdin.fileno())


def resume_command(
    run_dir: Annotated[Path, typer.Argument(help="Run folder written by `storyteller run` (holds run.json).")],
    interactive: Annotated[bool | None, typer.Option("--interactive/--no-interactive", help="Lines typed on stdin become the instruction (default: when stdin is a terminal).")] = None,
    live: LiveOption = None,
    smplx_model: SmplxModelOption = None,
    view: ViewOption = False,
    port: ViewPortOption = 8080,
    host: ViewHostOption = "127.0.0.1",
) -> None:
    """Go on with a run that was stopped (even by kill -9) from its last checkpoint."""
    from storyteller.orchestrator.session.run_manifest import ManifestError, read_manifest

    try:
        manifest = read_manifest(run_dir)
    except ManifestError as exc:
        fail(str(exc))
    _check_smplx_model(smplx_model)
    shown, typing = live_and_interactive(live, interactive, reads_stdin=True)
    _execute(manifest.arguments, out=run_dir, trace_path=run_dir / TRACE_JSONL, replay=None,
             thread_id=manifest.thread_id, resume=True, interactive=typing, live=shown, smplx_model=smplx_model,
             view=ViewAt(port, host) if view else None)


def replay_command(
    source: Annotated[Path, typer.Argument(help="Run folder (RUN_DIR/trace.jsonl) or a trace file next to its run.json.")],
    out: Annotated[Path, typer.Option("--out", "-o", help="Output folder of the replayed run.")],
    live: LiveOption = None,
    smplx_model: SmplxModelOption = None,
) -> None:
    """Replay a recorded run with no model loaded: same arguments (from run.json), same story, same motion."""
    from storyteller.orchestrator.session.run_manifest import ManifestError, read_manifest

    trace = source / TRACE_JSONL if source.is_dir() else source
    if not trace.exists() and not trace.is_symlink():  # a link to a device is read, and refused, later
        fail(f"{trace}: trace file not found")
    try:
        manifest = read_manifest(trace.parent)
    except ManifestError as exc:
        fail(str(exc))
    if out.resolve() == trace.parent.resolve():
        fail("--out must be a different folder than the replayed run's")
    _check_smplx_model(smplx_model)
    shown, _ = live_and_interactive(live, None, reads_stdin=False)
    _execute(manifest.arguments, out=out, trace_path=out / TRACE_JSONL, replay=trace, thread_id=None, resume=False,
             live=shown, smplx_model=smplx_model)


def _execute(
    args: RunArguments, *, out: Path, trace_path: Path | None, replay: Path | None, thread_id: str | None, resume: bool,
    smplx_model: Path | None = None,
    interactive: bool = False,
    live: bool = False,
    in_process_programs: bool = False,
    view: ViewAt | None = None,
) -> None:
    """Run the job and write its outputs. The event-program worker process (unless
    ``in_process_programs``) is started first, with the scene to load, so its imports and the
    scene's navigation grid overlap this process's imports of the job instead of delaying the
    first planning step; the job stops it when the story ends."""
    from storyteller.orchestrator.cli.collector import imports_paused
    from storyteller.orchestrator.session.run_folder_links import PlantedLinkError, refuse_planted_links

    try:  # before the folder is made or a worker started (run_story checks again, for its other callers)
        refuse_planted_links(out, args.names)
    except PlantedLinkError as exc:
        fail(str(exc))
    if not resume and trace_path is not None:
        refuse_earlier_trace(trace_path, out)
    with imports_paused():
        from storyteller.orchestrator.sandbox_worker import WorkerRunner
        from storyteller.sim.scene.bundled import resolve_scene
        from storyteller.sim.scene.files import SceneFileError

    try:
        scene_obj = resolve_scene(args.scene)
    except SceneFileError as exc:
        fail(str(exc))
    programs = None if in_process_programs else WorkerRunner()
    if programs is not None:
        programs.prestart(scene_obj)
    try:
        _run_job(args, scene_obj, programs, out=out, trace_path=trace_path, replay=replay, thread_id=thread_id,
                 resume=resume, smplx_model=smplx_model, interactive=interactive, live=live,
                 in_process_programs=in_process_programs, view=view)
    finally:
        if programs is not None:
            programs.close()  # stopped by the job already, unless it failed before it started


def refuse_earlier_trace(trace_path: Path, out: Path) -> None:
    """A new story (``run``, ``replay``) never writes into a trace that already holds one: the
    trace writer appends (``resume`` goes on with a file), so a second run into the same folder or
    ``--record`` file would make one file of two stories that replays as neither. One line, exit 2."""
    try:
        held = trace_path.lstat().st_size > 0
    except FileNotFoundError:
        return
    except OSError as exc:
        fail(f"{trace_path}: {exc.strerror or exc}")
    if held:
        hint = f"'storyteller resume {out}' goes on with it" if trace_path == out / TRACE_JSONL else "it is kept as it is"
        fail(f"{trace_path} already holds the trace of an earlier run ({hint}); choose another --out or --record, "
             "or remove it to start over")


@dataclass(frozen=True)
class ViewAt:
    """``--view``: serve the browser viewer of the run folder on ``host``:``port``."""

    port: int
    host: str


def _run_job(
    args: RunArguments, scene_obj: Scene, programs: WorkerRunner | None, *, out: Path, trace_path: Path | None,
    replay: Path | None, thread_id: str | None, resume: bool, smplx_model: Path | None, interactive: bool, live: bool,
    in_process_programs: bool, view: ViewAt | None,
) -> None:
    """The job in ``out`` (made here), with the viewer of ``view`` serving it from before the first
    frame until the command ends (after the story, until Ctrl-C)."""
    import importlib

    from storyteller.orchestrator.cli.collector import imports_paused

    with imports_paused():
        for module in (*OUTPUT_MODULES, *JOB_MODULES):
            importlib.import_module(module)

    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        _cannot_write(exc, out, resumable=False)
    viewer = _start_viewer(out, view, smplx_model) if view is not None else None
    try:
        _run_and_report(args, scene_obj, programs, out=out, trace_path=trace_path, replay=replay,
                        thread_id=thread_id, resume=resume, smplx_model=smplx_model, interactive=interactive,
                        live=live, in_process_programs=in_process_programs, viewer=viewer)
    finally:
        if viewer is not None:
            viewer.stop()


def _start_viewer(out: Path, view: ViewAt, smplx_model: Path | None) -> ViewerProcess:
    """The viewer of ``out`` in a process of its own (``storyteller.orchestrator.viewer.child``: the frames of
    the run keep their rate), listening, its address printed; exit 2 when it cannot start."""
    from storyteller.orchestrator.viewer.child import ViewerStartError, spawn_viewer

    try:
        viewer = spawn_viewer(out, port=view.port, host=view.host, smplx_model=smplx_model)
    except ViewerStartError as exc:  # an address this machine does not have, or cannot resolve
        fail(f"--view: {exc}")
    say(viewer.address)
    return viewer


def _serve_until_stopped(viewer: ViewerProcess) -> None:
    """After the story: the viewer goes on serving until SIGINT (Ctrl-C) or SIGTERM (or it ends)."""
    import signal
    import threading

    stopped = threading.Event()
    say(f"the story has ended; the viewer still serves it at {viewer.url} (Ctrl-C to stop)")
    previous = {signum: signal.signal(signum, lambda *_: stopped.set()) for signum in STOP_SIGNALS}
    try:
        while not stopped.wait(0.5) and viewer.alive:
            pass
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _run_and_report(
    args: RunArguments, scene_obj: Scene, programs: WorkerRunner | None, *, out: Path, trace_path: Path | None,
    replay: Path | None, thread_id: str | None, resume: bool, smplx_model: Path | None, interactive: bool, live: bool,
    in_process_programs: bool, viewer: ViewerProcess | None,
) -> None:
    import asyncio
    import sys

    from storyteller.orchestrator.cli.live_view import terminal_view
    from storyteller.orchestrator.session.run_job import StoryRun, run_story
    from storyteller.orchestrator.session.run_manifest import resume_command
    from storyteller.orchestrator.session.run_outputs import write_outputs
    from storyteller.orchestrator.session.run_setup import RunSetupError

    prompt = _typing_prompt(live, interactive)
    view = terminal_view(sys.stdout, stderr_is_terminal=sys.stderr.isatty(),
                         typed=(lambda: prompt.text) if prompt is not None else None) if live else None
    if prompt is not None and view is not None:
        prompt.on_change = view.refresh_soon

    def story_line(line: str) -> None:  # above the live view, or plain
        if view is not None:
            view.line(line)
        else:
            say(line)

    def show(e: StoryEvent, fps: int) -> None:
        story_line(_event_line(e, fps))

    def started(manifest: RunManifest) -> None:
        if replay is None:
            say(f"thread {plain(manifest.thread_id)}; to resume after a stop: {plain(resume_command(out))}", err=True)

    signals: list[int] = []  # the signals received, in order

    async def main() -> StoryRun:
        stop = asyncio.Event()
        loop = asyncio.get_running_loop()

        def on_signal(signum: int) -> None:
            signals.append(signum)
            stop.set()

        for signum in STOP_SIGNALS:
            loop.add_signal_handler(signum, on_signal, signum)
        try:
            async with view.running() if view is not None else contextlib.nullcontext(None) as status:
                return await run_story(
                    scene_obj,
                    args,
                    out=out,
                    trace_path=trace_path,
                    replay=replay,
                    thread_id=thread_id,
                    resume=resume,
                    interactive=interactive,
                    on_event=show,
                    on_instruction=lambda i, fps: story_line(f"[{i.frame / fps:7.1f}s] instruction ({i.source}): {plain(i.text)}"),
                    on_start=started,
                    on_resume=lambda frame, fps: say(f"resuming at frame {frame} ({frame / fps:.1f} s)", err=True),
                    in_process_programs=in_process_programs,
                    programs=programs,
                    stop=stop,
                    status=status,
                    stdin_reader=prompt.start if prompt is not None else None,
                )
        finally:
            if prompt is not None:
                prompt.close()  # the terminal's echo and line editing back
            for signum in STOP_SIGNALS:
                loop.remove_signal_handler(signum)

    try:
        run = asyncio.run(main())
    except RunSetupError as exc:
        fail(str(exc))
    except OSError as exc:
        _cannot_write(exc, out, resumable=replay is None)
    except Exception as exc:  # a bug or the environment: the session was cancelled and its files closed
        failed = _failed_write(exc, out)
        if failed is not None:  # runs.sqlite on a full disk: the write that failed, as for the trace
            _cannot_write(failed, out, resumable=replay is None)
        fail(f"the run stopped: {type(exc).__name__}: {plain(exc)}", code=1)
    result, fps = run.result, run.fps
    from storyteller.orchestrator.bodies.smplx_meshes import SmplxModelError

    failed_write = _failed_write(result.planner_error, out)  # the first write that failed is reported
    try:
        with _signals_interrupt():
            write_outputs(out, scene_obj, run.world, result, run.names, args.instruction, fps,
                          args.gif and not run.stopped, video=args.video and not run.stopped,
                          trace_path=trace_path, smplx_model=smplx_model)
    except SmplxModelError as exc:
        fail(str(exc))
    except OSError as exc:
        failed_write = failed_write or exc
    except _Interrupted as exc:
        signals.append(exc.signum)
    if failed_write is not None:
        _cannot_write(failed_write, out, resumable=replay is None)
    say(
        f"{result.frames} frames ({result.frames / fps:.1f} s), {result.steps} planning steps, "
        f"{sum(e.state == 'completed' for e in result.events)} events completed -> {plain(out)}"
    )
    if viewer is not None and not signals:
        _serve_until_stopped(viewer)
    if signals:
        signum = signals[0]
        again = "" if replay is not None else f"; go on with: {plain(resume_command(out))}"
        say(
            f"stopped by {signal_name(signum)} at frame {result.frames} ({result.frames / fps:.1f} s); "
            f"the story so far, its motion, trace and checkpoint are in {plain(out)}{again}",
            err=True,
        )
        raise typer.Exit(128 + signum)
    if result.planner_error is not None:
        import structlog

        from storyteller.agents.llm_port import ReplayMissError

        err = result.planner_error
        detail = err.diff if isinstance(err, ReplayMissError) else None
        message = str(err).split(f"\n{detail}")[0] if detail else str(err)
        if isinstance(err, ReplayMissError):
            # the trace cannot be applied: a bad file, one line and exit 2; the diff against the
            # recorded request is a log record (shown with --log-level INFO)
            structlog.get_logger("storyteller.replay").info("replay_miss_diff", diff=plain(detail or "", keep_newlines=True))
            say(f"error: cannot replay {plain(replay or trace_path)}: the recorded step does not apply: "
                       f"{one_line(message)} (--log-level INFO shows the diff)", err=True)
            raise typer.Exit(2)
        say(f"error: planning stopped: {type(err).__name__}: {one_line(message)}", err=True)
        raise typer.Exit(1)


OUTPUT_MODULES = ("storyteller.sim.export.bundle", "storyteller.sim.export.video", "storyteller.orchestrator.bodies.smplx_meshes")
"""Modules the outputs are written with at the end of a run: imported with the job's modules while
the garbage collector is paused (``storyteller.orchestrator.cli.collector``), not when the story is over."""
JOB_MODULES = (
    "storyteller.orchestrator.cli.live_view", "storyteller.orchestrator.session.run_job", "storyteller.orchestrator.session.run_outputs",
    "storyteller.orchestrator.session.run_manifest",
)
"""The job's own modules, imported the same way."""

STOP_SIGNALS = (2, 15)  # SIGINT, SIGTERM (the same numbers on every POSIX system)
"""The signals that stop a run cleanly; it exits with 128 + the signal's number (130, 143)."""


def signal_name(signum: int) -> str:
    import signal

    return signal.Signals(signum).name


class _Interrupted(Exception):
    def __init__(self, signum: int) -> None:
        super().__init__(signal_name(signum))
        self.signum = signum


@contextlib.contextmanager
def _signals_interrupt() -> Iterator[None]:
    """While the outputs are written, a stop signal ends the writing (the run stays resumable)."""
    import signal

    def interrupt(signum: int, _frame: object) -> None:
        raise _Interrupted(signum)

    previous = {signum: signal.signal(signum, interrupt) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def _failed_write(error: BaseException | None, out: Path) -> OSError | None:
    """``error`` (the planner's) as the write that failed, when it is one: an ``OSError`` (the
    trace), or SQLite's disk errors (``runs.sqlite``, whose checkpoints the planner writes)."""
    import sqlite3

    if isinstance(error, OSError):
        return error
    if isinstance(error, sqlite3.OperationalError) and any(
        words in str(error) for words in ("disk I/O error", "disk is full", "readonly database")
    ):
        return OSError(None, str(error), str(out / RUNS_DB))
    return None


def _cannot_write(exc: OSError, out: Path, *, resumable: bool) -> NoReturn:
    """A write that failed (a full disk, a file-size limit, no permission): one line, exit 1."""
    from storyteller.orchestrator.session.run_manifest import resume_command

    where = exc.filename if exc.filename is not None else out
    then = f"; once it can be written, go on with: {plain(resume_command(out))}" if resumable else ""
    say(
        f"error: cannot write {plain(where)}: {plain(exc.strerror or exc)}; what was written before is kept{then}",
        err=True,
    )
    raise typer.Exit(1)


__all__ = ["register", "replay_command", "resume_command", "run_command"]

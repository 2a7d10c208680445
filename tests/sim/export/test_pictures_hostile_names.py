"""Names in pictures are data (issue 22): a scene, an object, a character, its action, its event
and a title named with ESC[31m, BEL, U+202E (RLO) and U+2028 (line separator) are drawn with
each shown as its escape, in the top-down PNG, a run's final-state PNG and every picture of its
animation (whose moving labels are set anew each frame).

What is checked is what matplotlib's Agg renderer is asked to draw (``RendererAgg.draw_text``,
recorded), so a text drawn by any path of ``storyteller.sim.export`` counts. Before the escaping lived in
``sim`` these failed: every name reached the renderer raw.
"""

from __future__ import annotations

import unicodedata
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.backends.backend_agg import RendererAgg

from storyteller.sim.body.skeleton import NUM_JOINTS
from storyteller.sim.export.topdown import CharacterMarker, save_topdown_png
from storyteller.sim.export.video import RunRecording, animation_frames, save_run_png
from storyteller.sim.scene.model import Scene, SceneObject
from storyteller.sim.visible_text import UNSAFE_CATEGORIES
from storyteller.sim.world.character_track import CharacterTrack

HOSTILE = "x\x1b[31my\x07z\u202ew\u2028v"
SHOWN = "x\\x1b[31my\\x07z\\u202ew\\u2028v"


@pytest.fixture
def drawn(monkeypatch: pytest.MonkeyPatch) -> Iterator[list[str]]:
    """Every string the Agg renderer draws from now on."""
    texts: list[str] = []
    original: Callable[..., Any] = RendererAgg.draw_text

    def record(self: RendererAgg, gc: Any, x: float, y: float, s: str, *args: Any, **kwargs: Any) -> Any:
        texts.append(s)
        return original(self, gc, x, y, s, *args, **kwargs)

    monkeypatch.setattr(RendererAgg, "draw_text", record)
    yield texts


def _raw(texts: list[str]) -> list[str]:
    """The drawn strings holding a character that must be escaped (matplotlib draws a text line by
    line, so no drawn string holds a line break)."""
    return [t for t in texts if any(unicodedata.category(c) in UNSAFE_CATEGORIES for c in t)]


def _scene() -> Scene:
    table = SceneObject(name=f"table{HOSTILE}_1", label=f"table{HOSTILE}", idx=1, center=(2.0, 2.0, 0.375), size=(1.0, 0.8, 0.75))
    return Scene(name=f"room{HOSTILE}", bounds_min=(0.0, 0.0), bounds_max=(4.0, 4.0), objects=(table,))


def _recording() -> RunRecording:
    frames = 12
    rot = np.tile(np.eye(3), (frames, NUM_JOINTS, 1, 1))
    root = np.column_stack([np.linspace(0.5, 1.5, frames), np.full(frames, 0.5), np.full(frames, 0.93)])
    track = CharacterTrack(name=f"Ann{HOSTILE}", root_positions=root, local_rotations=rot,
                           action_labels=(f"walk{HOSTILE}",) * frames)
    return RunRecording(_scene(), {track.name: track}, {track.name: [f"meet{HOSTILE}"] * frames})


def test_the_topdown_png_draws_every_name_escaped(drawn: list[str], tmp_path: Path) -> None:
    marker = CharacterMarker(f"Ann{HOSTILE}", (1.0, 1.0), (1.0, 0.0), f"sit{HOSTILE}")
    save_topdown_png(tmp_path / "topdown.png", _scene(), characters=[marker], title=f"home{HOSTILE}",
                     captions=[f"events: meet{HOSTILE}", "t = 1.00 s"])
    assert _raw(drawn) == []
    shown = "\n".join(drawn)
    for name in ("table", "Ann", "sit", "home", "events: meet"):
        assert f"{name}{SHOWN}" in shown, (name, drawn)


def test_a_runs_png_and_every_animation_picture_draw_names_escaped(drawn: list[str], tmp_path: Path) -> None:
    rec = _recording()
    save_run_png(tmp_path / "final.png", rec, title=f"story{HOSTILE}")
    assert _raw(drawn) == [], drawn
    assert any(f"walk{SHOWN} / meet{SHOWN}" in t for t in drawn), drawn
    drawn.clear()
    pictures = animation_frames(rec, stride=3, title=f"story{HOSTILE}")
    assert len(pictures) == 5  # frames 0, 3, 6, 9 and the last
    assert _raw(drawn) == [], drawn
    # the moving label of each picture (moved and set anew, not made anew; one draw per line)
    assert drawn.count(f"Ann{SHOWN}") == 5, drawn
    assert drawn.count(f"walk{SHOWN} / meet{SHOWN}") == 5, drawn
    assert sum(f"story{SHOWN}" in t for t in drawn) == 1  # the static title, drawn once
    assert sum(f"table{SHOWN}" in t for t in drawn) == 1

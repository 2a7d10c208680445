"""Top-down pictures: shapes, determinism, and that every layer really draws something."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest
from matplotlib.image import imread
from matplotlib.quiver import Quiver

from storyteller.sim.export.topdown import CharacterMarker, draw_topdown, render_topdown_rgb, save_topdown_png
from storyteller.sim.scene.bundled import load_bundled_scene
from storyteller.sim.scene.model import Scene, SceneObject


@pytest.fixture(scope="module")
def small() -> Scene:
    objects = (
        SceneObject(
            name="table_1", label="table", idx=1, center=(2.0, 2.0, 0.375), size=(1.2, 0.8, 0.75)
        ),
        SceneObject(
            name="chair_1",
            label="chair",
            idx=1,
            center=(2.0, 1.2, 0.45),
            size=(0.5, 0.5, 0.9),
            facing=(0.0, 1.0),
            has_facing=True,
            sit_offset_vertical=0.45,
        ),
        SceneObject(name="cup_1", label="cup", idx=1, center=(2.0, 2.0, 0.8), size=(0.1, 0.1, 0.1)),
    )
    return Scene(name="small", bounds_min=(0.0, 0.0), bounds_max=(4.0, 4.0), objects=objects)


def _changed(a: np.ndarray, b: np.ndarray) -> int:
    return int(np.any(a != b, axis=-1).sum())


def test_rgb_frame_shape_and_determinism(small: Scene) -> None:
    a = render_topdown_rgb(small, size_px=401)
    b = render_topdown_rgb(small, size_px=401)
    assert a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] == 3
    assert a.shape[0] % 2 == 0 and a.shape[1] % 2 == 0  # video encoders want even sides
    assert a.shape[1] == 400
    assert np.array_equal(a, b)


def test_frames_of_one_scene_share_a_shape(small: Scene) -> None:
    plain = render_topdown_rgb(small, size_px=400)
    busy = render_topdown_rgb(
        small,
        size_px=400,
        characters=[CharacterMarker("Ann", (1.0, 3.0), (1.0, 0.0), "walk")],
        paths={"Ann": np.array([[0.5, 3.0], [1.0, 3.0]])},
        title="t = 1.0 s",
    )
    assert plain.shape == busy.shape


@pytest.mark.parametrize(
    "layers",
    [
        {"clusters": [["table_1", "chair_1", "cup_1"]]},
        {"nav_free": np.eye(13, dtype=bool), "nav_origin": (0.0, 0.0), "nav_cell_size": 0.3},
        {"characters": [CharacterMarker("Ann", (3.2, 3.2), (0.0, -1.0), "wave")]},
        {"characters": [CharacterMarker("Bob", (0.6, 0.6))]},
        {"paths": [np.array([[0.5, 0.5], [3.5, 0.5], [3.5, 3.5]])]},
        {"paths": {"Cy": [[0.5, 3.5], [1.5, 3.5]]}},
        {"title": "a title"},
        {"captions": ["event 3: Ann and Bob chat", "event 4: Cy makes coffee"]},
        {"show_names": False},
    ],
    ids=[
        "clusters",
        "grid",
        "character",
        "character-no-heading",
        "path-list",
        "path-mapping",
        "title",
        "captions",
        "no-names",
    ],
)
def test_each_layer_draws(small: Scene, layers: dict[str, Any]) -> None:
    base = render_topdown_rgb(small, size_px=400)
    drawn = render_topdown_rgb(small, size_px=400, **layers)
    assert _changed(base, drawn) > 30


def test_facing_arrows_only_for_objects_with_a_front(small: Scene) -> None:
    fig = draw_topdown(small)
    quivers = [c for c in fig.axes[0].collections if type(c).__name__ == "Quiver"]
    assert len(quivers) == 1 and isinstance(quivers[0], Quiver)
    assert quivers[0].N == 1  # the chair; not the table or the cup
    texts = {t.get_text() for t in fig.axes[0].texts}
    assert {"table_1", "chair_1", "cup_1"} <= texts


def test_bad_grid_mask_is_an_error(small: Scene) -> None:
    with pytest.raises(ValueError, match="2-D bool array"):
        render_topdown_rgb(small, nav_free=np.ones(5, dtype=bool))


def test_save_png_of_a_bundled_scene(tmp_path: Path) -> None:
    scene = load_bundled_scene("restaurant")
    path = save_topdown_png(tmp_path / "r.png", scene, title="restaurant", size_px=500)
    image = imread(path)
    frame = render_topdown_rgb(scene, title="restaurant", size_px=500)
    assert image.shape[:2] == frame.shape[:2]


def test_text_from_outside_is_drawn_as_text_not_mathtext(tmp_path: Path) -> None:
    """An object, a character, a caption and a title reading ``$\\bar$`` (invalid mathtext, which
    matplotlib would parse and fail on) are drawn literally."""
    odd = r"$\bar$"
    scene = Scene(name="odd", bounds_min=(0.0, 0.0), bounds_max=(4.0, 4.0), objects=(
        SceneObject(name=f"{odd}_1", label=odd, idx=1, center=(2.0, 2.0, 0.375), size=(1.2, 0.8, 0.75)),
    ))  # fmt: skip
    path = save_topdown_png(tmp_path / "odd.png", scene, title=odd, captions=[odd],
                            characters=[CharacterMarker(odd, (1.0, 1.0), (1.0, 0.0), odd)])
    assert imread(path).shape[2] in (3, 4)

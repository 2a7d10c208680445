"""The scene model: validation rules and derived geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from storyteller.sim.scene.model import NAME_PATTERN, Scene, SceneObject


def _obj(**changes: object) -> SceneObject:
    data: dict[str, object] = {
        "name": "chair_1",
        "label": "chair",
        "idx": 1,
        "center": (1.0, 2.0, 0.45),
        "size": (0.5, 0.6, 0.9),
        "facing": (0.0, 1.0),
        "has_facing": True,
        "sit_offset_horizontal": 0.1,
        "sit_offset_vertical": 0.45,
    }
    data.update(changes)
    return SceneObject.model_validate(data)


def test_derived_geometry() -> None:
    chair = _obj(facing=(1.0, 0.0))
    assert (chair.width, chair.depth, chair.height) == (0.5, 0.6, 0.9)
    assert chair.z_min == pytest.approx(0.0) and chair.z_max == pytest.approx(0.9)
    assert chair.right == pytest.approx([0.0, -1.0])  # facing +x: right is -y
    assert chair.yaw == pytest.approx(0.0)
    corners = chair.footprint()
    assert corners.min(axis=0) == pytest.approx([1.0 - 0.3, 2.0 - 0.25])  # depth along x
    assert corners.max(axis=0) == pytest.approx([1.0 + 0.3, 2.0 + 0.25])
    assert chair.seat_point() == pytest.approx([1.0 + 0.6 * 0.1, 2.0])
    assert chair.is_seat and not _obj(sit_offset_vertical=0.0).is_seat
    local = chair.to_local(np.array([[1.0, 1.0], [2.0, 2.0]]))
    assert local == pytest.approx(np.array([[1.0, 0.0], [0.0, 1.0]]))  # [right, forward]
    assert chair.contains_xy(np.array([1.29, 2.24])) and not chair.contains_xy(
        np.array([1.31, 2.0])
    )
    assert chair.contains_xy(np.array([1.35, 2.0]), margin=0.06)


def test_facing_is_normalised_and_unit_facing_kept_exactly() -> None:
    assert _obj(facing=(3.0, 4.0)).facing == pytest.approx((0.6, 0.8))
    exact = (0.9510568248838477, 0.3090160446349902)
    assert _obj(facing=exact).facing == exact
    again = _obj(facing=_obj(facing=(0.3, 0.7)).facing).facing
    assert again == _obj(facing=(0.3, 0.7)).facing  # idempotent


def test_a_facing_whose_length_overflows_is_still_a_unit_direction() -> None:
    """[1.7e308, -1.7e308] is a direction whose length is inf: it was divided by inf, stored as
    [0, -0], a zero facing past the rule that refuses one (hostile scene attack, issue 22)."""
    assert _obj(facing=(1.7e308, -1.7e308)).facing == pytest.approx((math.sqrt(0.5), -math.sqrt(0.5)))
    assert _obj(facing=(1.7976931348623157e308, 1.0)).facing == pytest.approx((1.0, 0.0))


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"size": (0.5, -0.1, 0.9)}, "size component must be >= 0"),
        ({"facing": (0.0, 0.0)}, "non-zero"),
        ({"name": "chair_2"}, "name must be"),
        ({"idx": -1}, "greater than or equal to 0"),
        ({"center": (0.0, math.nan, 0.0)}, "finite number"),
        ({"colour": "red"}, "Extra inputs"),
    ],
)
def test_object_validation(changes: dict[str, object], message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        _obj(**changes)


def test_scene_validation() -> None:
    a = _obj()
    with pytest.raises(ValidationError, match="duplicate object name 'chair_1'"):
        Scene(name="s", bounds_min=(0, 0), bounds_max=(5, 5), objects=(a, a))
    with pytest.raises(ValidationError, match="bounds_max must be greater"):
        Scene(name="s", bounds_min=(0, 0), bounds_max=(5, 0), objects=(a,))
    scene = Scene(
        name="s", bounds_min=(0, 0), bounds_max=(5, 5), objects=(a, _obj(name="chair_2", idx=2))
    )
    assert (
        scene.get("chair_2").idx == 2
        and scene.object_names == ["chair_1", "chair_2"]
        and scene.labels == ["chair"]
    )
    with pytest.raises(KeyError):
        scene.get("chair_3")
    with pytest.raises(ValidationError):
        scene.model_copy().__class__.model_validate({**scene.model_dump(), "format": "other/2"})


def test_name_pattern() -> None:
    m = NAME_PATTERN.match("coffee_maker_12")
    assert m is not None and m.group("label") == "coffee_maker" and m.group("idx") == "12"
    assert NAME_PATTERN.match("Chair_1") is None


@settings(max_examples=60, deadline=None)
@given(
    yaw=st.floats(-math.pi, math.pi),
    w=st.floats(0.05, 3.0),
    d=st.floats(0.05, 3.0),
    u=st.floats(-0.499, 0.499),
    v=st.floats(-0.499, 0.499),
)
def test_footprint_and_local_frame_agree(
    yaw: float, w: float, d: float, u: float, v: float
) -> None:
    obj = _obj(facing=(math.cos(yaw), math.sin(yaw)), size=(w, d, 1.0))
    corners = obj.footprint()
    local = obj.to_local(corners)
    assert np.abs(local) == pytest.approx(np.tile([w / 2, d / 2], (4, 1)), abs=1e-9)
    # a point given in local coordinates maps back inside the footprint
    point = obj.center_xy + obj.right * (u * w) + np.asarray(obj.facing) * (v * d)
    assert obj.to_local(point) == pytest.approx([u * w, v * d], abs=1e-9)
    assert bool(obj.contains_xy(point))
    outside = obj.center_xy + np.asarray(obj.facing) * (d / 2 + 0.01)
    assert not bool(obj.contains_xy(outside))
    # counter-clockwise corners: positive signed area equal to w * d
    x, y = corners[:, 0], corners[:, 1]
    area = 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))
    assert area == pytest.approx(w * d, rel=1e-9)

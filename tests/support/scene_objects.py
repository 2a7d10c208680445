"""Scene objects for tests that build small scenes by hand: a box on the floor at (x, y)."""

from __future__ import annotations

from storyteller.sim.scene.model import SceneObject


def box(label: str, idx: int, x: float, y: float, *, seat: bool = False, facing: tuple[float, float] = (0.0, 1.0),
        size: tuple[float, float, float] = (0.5, 0.5, 0.9), front: bool | None = None) -> SceneObject:  # fmt: skip
    """``label_idx`` standing on the floor at (x, y), ``size`` (w, d, h) m, facing ``facing``; a
    ``seat`` has a sitting offset; ``front`` (default: a seat has one) says whether the facing counts."""
    return SceneObject(
        name=f"{label}_{idx}", label=label, idx=idx, center=(x, y, size[2] / 2), size=size, facing=facing,
        has_facing=seat if front is None else front, sit_offset_vertical=0.45 if seat else 0.0,
    )

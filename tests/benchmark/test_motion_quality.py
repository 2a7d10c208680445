"""Motion-quality metrics (benchmark/motion_quality.py) and the shipped real-mocap config."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from storyteller.benchmark.motion_quality import (
    DEFAULT_CONFIG,
    compare_clips,
    format_table,
    main,
    motion_stats,
    pooled,
    shipped_config,
    simulate_walkers,
)
from storyteller.orchestrator.cache_paths import motion_cache_dir
from storyteller.orchestrator.reference_data import DEFAULT_MOCAP, PROJECT_ROOT
from storyteller.sim.motion.config import load_motion_config
from storyteller.sim.motion.database import load_databases
from storyteller.sim.motion.matching import MotionMatcher
from tests.support.reference import MOCAP, requires_mocap, requires_reference


def _walker(frames: int = 61, speed: float = 1.2, slide: float = 0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A rigid body moving along x at ``speed``; its toes (joints 10, 11) slide at ``slide`` m/s
    relative to the ground while marked in contact on alternate half-seconds."""
    t = np.arange(frames) / 30.0
    joints = np.zeros((frames, 22, 3))
    joints[:, :, 0] = (speed * t)[:, None]
    joints[:, :, 2] = 0.5
    joints[:, [10, 11], 2] = 0.02
    contacts = np.zeros((frames, 2), dtype=bool)
    contacts[:, 0] = (t % 1.0) < 0.5
    contacts[:, 1] = ~contacts[:, 0]
    # planted toes stay at a fixed x (plus the slide) while in contact
    for k in (0, 1):
        start = None
        for f in range(frames):
            if contacts[f, k] and start is None:
                start = f
            if not contacts[f, k]:
                start = None
            if start is not None:
                joints[f, 10 + k, 0] = joints[start, 10 + k, 0] + slide * (f - start) / 30.0
    return joints, joints[:, 0, :2], contacts


def test_planted_feet_do_not_slide_and_a_skating_foot_does() -> None:
    joints, root, contacts = _walker()
    s = motion_stats(joints, root, contacts)
    assert s.slide == pytest.approx(0.0, abs=1e-9)
    assert s.speed == pytest.approx(1.2)
    assert s.cadence == pytest.approx(4 / (60 / 30 / 60), rel=0.01)  # 4 onsets in 2 s
    assert s.floor == pytest.approx(0.02)
    assert s.bob == pytest.approx(0.0)
    skate = motion_stats(*_walker(slide=0.3))
    assert skate.slide == pytest.approx(0.3, rel=1e-6)


def test_jerk_is_zero_for_uniform_motion_and_grows_with_shaking() -> None:
    joints, root, contacts = _walker()
    assert motion_stats(joints, root, contacts).jerk == pytest.approx(0.0, abs=1e-6)
    shaken = joints.copy()
    shaken[::2, :, 2] += 0.01
    assert motion_stats(shaken, root, contacts).jerk > 100.0
    assert motion_stats(shaken, root, contacts).bob > 0.004


def test_pooling_weights_by_frames_and_short_motions_are_refused() -> None:
    a = motion_stats(*_walker(frames=31, slide=0.0))
    b = motion_stats(*_walker(frames=91, slide=0.4))
    p = pooled([a, b])
    assert p.frames == 122
    assert a.slide < p.slide < b.slide
    with pytest.raises(ValueError, match="at least 4 frames"):
        motion_stats(np.zeros((3, 22, 3)), np.zeros((3, 2)), np.zeros((3, 2), bool))
    with pytest.raises(ValueError, match="nothing"):
        pooled([])


def test_shipped_config_root_is_the_default_mocap_folder() -> None:
    root = load_motion_config(DEFAULT_CONFIG).root
    assert (DEFAULT_CONFIG.parent / root).resolve() == (PROJECT_ROOT / DEFAULT_MOCAP).resolve()


@requires_mocap
def test_shipped_config_reads_the_shared_clips_in_place() -> None:
    config = shipped_config()
    assert {e.label for e in config.clips} >= {"walk", "wave", "dance"}
    for entry in config.clips:
        path = config.resolve(entry)
        assert path.is_file(), path
        assert MOCAP.resolve() in path.resolve().parents  # read from ../shared, not copied


@requires_mocap
def test_real_walks_against_procedural_walks(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path / "cache"))
    result = compare_clips(shipped_config(), ["walk", "wave"])
    proc, real = result["walk"]
    assert 0.5 < real.speed < 1.6 and 0.5 < proc.speed < 1.6  # both walk at human speeds
    assert real.cadence > 0 and proc.cadence > 0
    assert real.jerk > proc.jerk  # sensor noise in real data; the generator is smooth
    table = format_table([(k, p, r) for k, (p, r) in result.items()])
    assert "walk" in table and "proc/real" in table and "wave" in table


@requires_reference
def test_synthesized_walkers_are_measured() -> None:
    stats = simulate_walkers(MotionMatcher(load_databases(["walk", "idle"], cache_dir=motion_cache_dir())), 1, 4.0, seed=3)
    assert stats.frames == 120
    assert 0.0 <= stats.slide < 1.0 and stats.speed > 0.05
    assert stats.floor > -0.1


@requires_mocap
@pytest.mark.slow
def test_cli_prints_the_clip_table(capsys: pytest.CaptureFixture[str], tmp_path: Path,
                                   monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path / "cache"))
    assert main(["--walkers", "0"]) == 0
    out = capsys.readouterr().out
    assert "proc/real" in out and "dance" in out

"""Importers on the real clips in ../shared/mocap, the AMASS npz round trip, and the config."""

from __future__ import annotations

import struct
import zipfile
from pathlib import Path
from typing import TypedDict

import bvh as independent_bvh
import numpy as np
import pytest
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import JOINT_INDEX, REST_OFFSETS, matrix_to_axis_angle
from storyteller.sim.motion.clips import MotionClip, foot_sliding
from storyteller.sim.motion.config import MotionConfigError, build_databases_from_config, load_motion_config
from storyteller.sim.motion.sources.amass_import import import_amass
from storyteller.sim.motion.sources.bvh_import import (
    MocapImportError,
    auto_joint_mapping,
    import_bvh,
    parse_bvh,
)
from storyteller.sim.motion.sources.procedural_actions import action_clip
from tests.support.reference import MOCAP, requires_mocap

HEAD = JOINT_INDEX["head"]


def _stats(clip: MotionClip) -> tuple[NDArray[np.float64], float, float]:
    pos = clip.joint_positions()
    height = float(np.median(pos[:, HEAD, 2] - pos[:, [10, 11], 2].min(axis=1)))
    speed = float(np.linalg.norm(np.diff(clip.root_xy, axis=0), axis=1).mean() * 30)
    return pos, height, speed


@requires_mocap
@pytest.mark.parametrize(
    ("rel", "start", "end", "fps", "min_speed", "max_speed"),
    [
        ("cmu/daz/05_01.bvh", 1, None, None, 0.6, 1.4),  # Daz skeleton, y up, walk
        ("cmu/max/131_01.bvh", 0, 500, None, 0.0, 1.6),  # 3ds Max skeleton, start walk
        ("fair_animated_drawings/wave_hello.bvh", 0, None, None, 0.0, 0.2),  # z up, wave
        ("cmu/daz/60_02.bvh", 1, 241, 60.0, 0.0, 1.5),  # salsa: true rate is 60 fps
    ],
)
def test_bvh_import_of_real_clips(rel: str, start: int, end: int | None, fps: float | None,
                                  min_speed: float, max_speed: float) -> None:
    path = MOCAP / rel
    data = parse_bvh(path)
    clip = import_bvh(path, "walk", start=start, end=end, fps=fps)
    n_src = (len(data.frames) if end is None else end) - start
    rate = fps or 1.0 / data.frame_time
    assert clip.local_rotations.shape[1:] == (22, 3, 3) and clip.fps == 30
    assert clip.num_frames == pytest.approx((n_src - 1) / rate * 30 + 1, abs=1.0)
    pos, height, speed = _stats(clip)
    assert np.isfinite(pos).all()
    assert 1.3 < height < 1.8  # a standing adult's head height on our skeleton
    assert 0.75 < np.median(clip.pelvis[:, 2]) < 1.0
    assert min_speed <= speed <= max_speed
    assert pos[:, [10, 11], 2].min() > -0.05  # feet do not sink under the floor


@requires_mocap
def test_wave_raises_the_right_hand_and_walk_slides_little() -> None:
    wave = import_bvh(MOCAP / "fair_animated_drawings/wave_hello.bvh", "wave")
    pos = wave.joint_positions()
    # the actor holds the right arm out at shoulder height (as in the source) and drops the left
    right, left = pos[:, JOINT_INDEX["right_wrist"], 2], pos[:, JOINT_INDEX["left_wrist"], 2]
    assert (right > pos[:, JOINT_INDEX["right_shoulder"], 2] - 0.15).mean() > 0.6
    assert (left < 0.9).mean() > 0.4 and right.mean() > left.mean() + 0.1
    walk = import_bvh(MOCAP / "cmu/max/131_01.bvh", "walk")
    assert foot_sliding(walk.joint_positions(), walk.contacts) < 0.3


@requires_mocap
def test_parser_agrees_with_an_independent_reader() -> None:
    path = MOCAP / "cmu/max/131_02.bvh"
    ours = parse_bvh(path)
    theirs = independent_bvh.Bvh(path.read_text())
    assert theirs.nframes == len(ours.frames)
    assert theirs.frame_time == pytest.approx(ours.frame_time)
    assert list(theirs.get_joints_names()) == list(ours.names)
    j = ours.names.index("LeftKnee")
    col = sum(len(c) for c in ours.channels[:j])
    for frame in (0, 500):
        assert [float(v) for v in theirs.frames[frame][col : col + 3]] == pytest.approx(list(ours.frames[frame, col : col + 3]))
    mapping = auto_joint_mapping(ours.names)
    assert mapping["left_shoulder"] == "LeftShoulder" and mapping["left_collar"] == "LeftCollar"


def test_bad_bvh_files_give_typed_errors(tmp_path: Path) -> None:
    for text in ("", "HIERARCHY\nROOT hips {\n", "not a bvh", "HIERARCHY\nROOT Hips\n{\nOFFSET 0 0 0\nCHANNELS 3 Xrotation Yrotation Zrotation\n}\nMOTION\nFrames: 5\nFrame Time: 0.1\n0 0 0\n"):
        p = tmp_path / "bad.bvh"
        p.write_text(text)
        with pytest.raises(MocapImportError, match=r"bad\.bvh"):
            import_bvh(p, "walk")
    with pytest.raises(MocapImportError, match="cannot read"):
        parse_bvh(tmp_path / "missing.bvh")


class AmassArrays(TypedDict):
    """The arrays of an AMASS ``.npz`` (SMPL-X layout: 165 pose values per frame)."""

    poses: NDArray[np.float64]
    trans: NDArray[np.float64]
    mocap_frame_rate: NDArray[np.float64]
    betas: NDArray[np.float64]
    gender: NDArray[np.str_]


def _amass_arrays(clip: MotionClip) -> AmassArrays:
    aa = matrix_to_axis_angle(clip.local_rotations).reshape(clip.num_frames, 66)
    poses = np.concatenate([aa, np.zeros((clip.num_frames, 99))], axis=1)
    return {"poses": poses, "trans": clip.pelvis - REST_OFFSETS[0], "mocap_frame_rate": np.array(30.0),
            "betas": np.zeros(16), "gender": np.array("neutral")}


def test_amass_npz_round_trip(tmp_path: Path) -> None:
    clip = action_clip("drink")
    path = tmp_path / "drink.npz"
    np.savez(path, **_amass_arrays(clip))
    back = import_amass(path, "drink", snap_to_floor=False)
    assert back.num_frames == clip.num_frames
    assert np.allclose(back.local_rotations, clip.local_rotations, atol=1e-9)
    assert np.allclose(back.pelvis, clip.pelvis, atol=1e-12)
    assert np.allclose(back.joint_positions(), clip.joint_positions(), atol=1e-9)
    # root_orient / pose_body layout at 60 fps resamples to 30 fps
    a = _amass_arrays(clip)
    np.savez(tmp_path / "split.npz", root_orient=a["poses"][:, :3], pose_body=a["poses"][:, 3:66], trans=a["trans"],
             mocap_framerate=np.array(60.0))
    half = import_amass(tmp_path / "split.npz", "drink", snap_to_floor=False)
    assert half.num_frames == (clip.num_frames - 1) // 2 + 1
    np.savez(tmp_path / "broken.npz", poses=a["poses"])
    with pytest.raises(MocapImportError, match="trans"):
        import_amass(tmp_path / "broken.npz", "drink")


@requires_mocap
def test_config_builds_databases_from_real_mocap(tmp_path: Path) -> None:
    cache = tmp_path / "cache" / "motion"
    cfg = tmp_path / "motion.toml"
    cfg.write_text(f'root = "{MOCAP.as_posix()}"\n[[clips]]\nfile = "cmu/daz/07_03.bvh"\nlabel = "walk"\nstart = 1\n'
                   '[[clips]]\nfile = "fair_animated_drawings/wave_hello.bvh"\nlabel = "wave"\n')
    config = load_motion_config(cfg)
    dbs = build_databases_from_config(config, ["walk", "wave", "chat"], cache_dir=cache)
    assert dbs["walk"].clip_names == ("07_03[1:416]",)
    assert dbs["wave"].num_frames > 150
    assert dbs["chat"].clip_names == ("chat_proc",)  # procedural fill-in
    assert len(list(cache.glob("*.npz"))) == 3  # two imports, the procedural chat database
    again = build_databases_from_config(config, ["walk"], cache_dir=cache)  # cached import
    assert np.allclose(again["walk"].pelvis, dbs["walk"].pelvis)


def test_config_errors_name_file_and_field(tmp_path: Path) -> None:
    cfg = tmp_path / "m.toml"
    cfg.write_text('[[clips]]\nfile = "x.bvh"\nlabel = "walk"\nspeed = 3\n')
    with pytest.raises(MotionConfigError, match=r"m\.toml \(clips\.0\.speed\)"):
        load_motion_config(cfg)
    cfg.write_text('[[clips]]\nfile = "x.bvh"\nlabel = "wlak"\n')
    with pytest.raises(MotionConfigError, match="did you mean 'walk'"):
        load_motion_config(cfg)
    cfg.write_text("clips = [")
    with pytest.raises(MotionConfigError, match="not valid TOML"):
        load_motion_config(cfg)
    cfg.write_text('[[clips]]\nfile = "nope.bvh"\nlabel = "walk"\n')
    with pytest.raises(MotionConfigError, match="not found"):
        build_databases_from_config(load_motion_config(cfg), ["walk"])


def test_huge_clip_files_are_refused_unread(tmp_path: Path) -> None:
    """Found by the hostile corpus: a motion config naming a sparse 3 GB .bvh was hashed and read
    whole (killed at 10 s), a zip-bomb .npz inflated to 1.7 GB; now sizes are checked first."""
    with open(tmp_path / "big.bvh", "wb") as f:
        f.truncate(3 << 30)  # sparse: nothing on disk
    cfg = tmp_path / "m.toml"
    cfg.write_text('[[clips]]\nfile = "big.bvh"\nlabel = "walk"\n')
    with pytest.raises(MotionConfigError, match="bytes a clip file may have"):
        build_databases_from_config(load_motion_config(cfg), ["walk"], cache_dir=tmp_path / "cache")
    with pytest.raises(MocapImportError, match="more than"):
        parse_bvh(tmp_path / "big.bvh")  # the parser's own bound
    header = b"{'descr': '<f8', 'fortran_order': False, 'shape': (100000000, 165), }"
    header += b" " * (63 - (len(header) + 10) % 64) + b"\n"
    with zipfile.ZipFile(tmp_path / "bomb.npz", "w") as z:  # 132 GB declared, 8 bytes held
        z.writestr("poses.npy", b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + bytes(8))
    with pytest.raises(MocapImportError, match="claims more bytes than its entry holds"):
        import_amass(tmp_path / "bomb.npz", "walk")


@requires_mocap
@pytest.mark.parametrize(("name", "speed", "turn_deg"), [
    ("dataset-1_walk_normal_001.bvh", 1.20, 0.0),
    ("dataset-2_walk-turn-left_normal_001.bvh", None, 100.0),
    ("dataset-2_walk-turn-right_normal_001.bvh", None, -100.0),
])
def test_a_bvh_whose_rest_pose_lies_down_imports_standing(name: str, speed: float | None, turn_deg: float) -> None:
    # Bandai Namco's files: the rest pose has its bones along +x (not an upright T-pose) and
    # every joint carries position channels holding its whole translation (not an offset delta).
    mapping = {"left_hip": "UpperLeg_L", "right_hip": "UpperLeg_R", "left_knee": "LowerLeg_L",
               "right_knee": "LowerLeg_R", "left_ankle": "Foot_L", "right_ankle": "Foot_R",
               "left_foot": "Toes_L", "right_foot": "Toes_R", "left_shoulder": "UpperArm_L",
               "right_shoulder": "UpperArm_R", "left_elbow": "LowerArm_L", "right_elbow": "LowerArm_R",
               "left_wrist": "Hand_L", "right_wrist": "Hand_R"}
    clip = import_bvh(MOCAP / "bandai_namco" / name, "walk", mapping=mapping)
    joints = clip.joint_positions()
    assert 0.85 < float(np.median(joints[:, 0, 2])) < 1.0  # pelvis at a standing adult's height
    assert float(np.median(joints[:, HEAD, 2] - joints[:, 0, 2])) > 0.5  # head above it
    if speed is not None:  # the file's README: a straight walk at about 1.2 m/s
        v = np.linalg.norm(np.diff(clip.root_xy, axis=0), axis=-1).mean() * clip.fps
        assert v == pytest.approx(speed, abs=0.1)
    turned = np.degrees(np.unwrap(clip.heading)[-1] - np.unwrap(clip.heading)[0])
    assert turned == pytest.approx(turn_deg, abs=25.0)

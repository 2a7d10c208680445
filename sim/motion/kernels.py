"""Compiled (numba) kernels of the motion-matching step, bit-identical to the numpy path.

The matcher's per-frame work on all characters at once: inertialization (offsets at a switch,
spring decay), the output pose (offset rotations applied to the database frame, root yaw,
pelvis placed on the root), forward kinematics and query features for searches, and the exact
nearest-frame scan. Each kernel reproduces the arithmetic of the numpy / scipy code it
replaces operation by operation, so the results are the same floats:

- scipy's ``Rotation`` (Cython backend) for rotation vector <-> matrix: the same formulas in
  the same order (``rotvec_to_matrix``, ``matrix_to_rotvec``);
- numpy's ``@`` on 3x3 / 4x4 float64 matrices, which calls OpenBLAS dgemm: each element is a
  chain of fused multiply-adds over k (``a0*b0``, then ``fma(a1, b1, .)``, ...), reproduced
  with LLVM's ``fma`` (``_fma``); on a machine whose BLAS kernel does not fuse, results
  differ in the last bit only (the equivalence test allows 1e-12 and checks decisions exactly);
- element-wise numpy expressions: the same operations in the same order (numba does not
  contract ``a * b + c`` into an fma unless asked); ``math.sin`` / ``cos`` / ``atan2`` / ``sqrt``
  are the C library's, as numpy's float64 ufuncs are here.

Shapes: N characters, 22 joints; rotations (..., 3, 3) float64 C-contiguous.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, cast

import numpy as np
from numba import njit, types
from numba.extending import intrinsic
from numpy.typing import NDArray

from storyteller.sim.body.skeleton import NUM_JOINTS, PARENTS, REST_OFFSETS

# skeleton data, passed to the kernels as arguments (a global would be frozen into numba's
# on-disk cache, which only notices changes to this file)
PARENT_INDEX = np.array(PARENTS, dtype=np.int64)
OFFSETS = np.ascontiguousarray(REST_OFFSETS, dtype=np.float64)


def _fma_typing(typingctx: object, a: object, b: object, c: object) -> tuple[Any, Callable[..., Any]]:
    """a * b + c with one rounding (LLVM ``llvm.fma.f64``): numba's typing and codegen."""
    sig = types.float64(types.float64, types.float64, types.float64)

    def codegen(context: object, builder: Any, signature: object, args: Sequence[Any]) -> Any:
        return builder.fma(args[0], args[1], args[2])

    return sig, codegen


# ``intrinsic`` hides the typing context: compiled code calls it as ``_fma(a, b, c)``
_fma = cast("Callable[[float, float, float], float]", intrinsic(_fma_typing))


@njit(cache=True, inline="always")
def _matmul3(a: NDArray[np.float64], b: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """out = a @ b for 3x3 (out may not alias a or b), as numpy's dgemm-backed matmul."""
    for i in range(3):
        for j in range(3):
            acc = a[i, 0] * b[0, j]
            acc = _fma(a[i, 1], b[1, j], acc)
            out[i, j] = _fma(a[i, 2], b[2, j], acc)


@njit(cache=True, inline="always")
def _matmul3_bt(a: NDArray[np.float64], b: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """out = a @ b.T for 3x3."""
    for i in range(3):
        for j in range(3):
            acc = a[i, 0] * b[j, 0]
            acc = _fma(a[i, 1], b[j, 1], acc)
            out[i, j] = _fma(a[i, 2], b[j, 2], acc)


@njit(cache=True, inline="always")
def _rotvec_to_matrix(x: float, y: float, z: float, out: NDArray[np.float64]) -> None:
    """scipy ``Rotation.from_rotvec(v).as_matrix()`` for one vector."""
    angle = math.sqrt(x * x + y * y + z * z)
    if angle <= 1e-3:
        angle2 = angle * angle
        scale = 0.5 - angle2 / 48 + angle2 * angle2 / 3840
    else:
        scale = math.sin(angle / 2) / angle
    qx, qy, qz, qw = scale * x, scale * y, scale * z, math.cos(angle / 2)
    x2, y2, z2, w2 = qx * qx, qy * qy, qz * qz, qw * qw
    xy, zw, xz, yw, yz, xw = qx * qy, qz * qw, qx * qz, qy * qw, qy * qz, qx * qw
    out[0, 0] = x2 - y2 - z2 + w2
    out[1, 0] = 2 * (xy + zw)
    out[2, 0] = 2 * (xz - yw)
    out[0, 1] = 2 * (xy - zw)
    out[1, 1] = -x2 + y2 - z2 + w2
    out[2, 1] = 2 * (yz + xw)
    out[0, 2] = 2 * (xz + yw)
    out[1, 2] = 2 * (yz - xw)
    out[2, 2] = -x2 - y2 + z2 + w2


@njit(cache=True, inline="always")
def _matrix_to_rotvec(m: NDArray[np.float64], out: NDArray[np.float64]) -> None:
    """scipy ``Rotation.from_matrix(m, assume_valid=True).as_rotvec()`` for one matrix."""
    d0, d1, d2 = m[0, 0], m[1, 1], m[2, 2]
    d3 = m[0, 0] + m[1, 1] + m[2, 2]
    choice, vmax = 0, d0
    if d1 > vmax:
        choice, vmax = 1, d1
    if d2 > vmax:
        choice, vmax = 2, d2
    if d3 > vmax:
        choice = 3
    q = np.empty(4)
    if choice != 3:
        i = choice
        j = (i + 1) % 3
        k = (j + 1) % 3
        q[i] = 1 - d3 + 2 * m[i, i]
        q[j] = m[j, i] + m[i, j]
        q[k] = m[k, i] + m[i, k]
        q[3] = m[k, j] - m[j, k]
    else:
        q[0] = m[2, 1] - m[1, 2]
        q[1] = m[0, 2] - m[2, 0]
        q[2] = m[1, 0] - m[0, 1]
        q[3] = 1 + d3
    norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if norm != 0:
        q[0] /= norm
        q[1] /= norm
        q[2] /= norm
        q[3] /= norm
    if (q[3] < 0 or (q[3] == 0 and q[0] < 0) or (q[3] == 0 and q[0] == 0 and q[1] < 0)
            or (q[3] == 0 and q[0] == 0 and q[1] == 0 and q[2] < 0)):
        q[0] *= -1.0
        q[1] *= -1.0
        q[2] *= -1.0
        q[3] *= -1.0
    angle = 2 * math.atan2(math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2]), q[3])
    if angle <= 1e-3:
        angle2 = angle * angle
        scale = 2 + angle2 / 12 + 7 * angle2 * angle2 / 2880
    else:
        scale = angle / math.sin(angle / 2)
    out[0] = scale * q[0]
    out[1] = scale * q[1]
    out[2] = scale * q[2]


@njit(cache=True)
def rotvec_to_matrix(v: NDArray[np.float64]) -> NDArray[np.float64]:
    """Rotation vectors (K,3) -> matrices (K,3,3), as ``storyteller.sim.motion.inertialization.rotation_exp``."""
    out = np.empty((v.shape[0], 3, 3))
    for r in range(v.shape[0]):
        _rotvec_to_matrix(v[r, 0], v[r, 1], v[r, 2], out[r])
    return out


@njit(cache=True)
def matrix_to_rotvec(m: NDArray[np.float64]) -> NDArray[np.float64]:
    """Matrices (K,3,3) -> rotation vectors (K,3), as ``storyteller.sim.motion.inertialization.rotation_log``."""
    out = np.empty((m.shape[0], 3))
    for r in range(m.shape[0]):
        _matrix_to_rotvec(m[r], out[r])
    return out


@njit(cache=True)
def matmul3(a: NDArray[np.float64], b: NDArray[np.float64]) -> NDArray[np.float64]:
    """(K,3,3) @ (K,3,3), as numpy's matmul."""
    out = np.empty((a.shape[0], 3, 3))
    for r in range(a.shape[0]):
        _matmul3(a[r], b[r], out[r])
    return out


@njit(cache=True, inline="always")
def _place_on_root(real: NDArray[np.float64], aux: NDArray[np.float64], pos: NDArray[np.float64], r0: NDArray[np.float64],
                   pelvis: NDArray[np.float64], contacts: NDArray[np.bool_], a: NDArray[np.float64]) -> None:
    """One character of ``step_poses``: joint 0's rotation ``r0`` (3,3) turned in place by
    rot_z(heading), the pelvis (frame ``aux[:3]`` + offset ``pos`` + seat correction) placed on
    the root, and the frame's foot contacts; ``real``: heading, root x, root y, seat correction;
    ``a``: a (3,3) scratch array."""
    ch, sh = math.cos(real[0]), math.sin(real[0])
    for c in range(3):
        a[0, c] = _fma(0.0, r0[2, c], _fma(-sh, r0[1, c], ch * r0[0, c]))
        a[1, c] = _fma(0.0, r0[2, c], _fma(ch, r0[1, c], sh * r0[0, c]))
        a[2, c] = _fma(1.0, r0[2, c], _fma(0.0, r0[1, c], 0.0 * r0[0, c]))
    for r in range(3):
        for c in range(3):
            r0[r, c] = a[r, c]
    px = aux[0] + pos[0]
    py = aux[1] + pos[1]
    pz = aux[2] + pos[2] + real[3]
    pelvis[0] = real[1] + (ch * px - sh * py)
    pelvis[1] = real[2] + (sh * px + ch * py)
    pelvis[2] = pz
    contacts[0] = aux[3] != 0.0
    contacts[1] = aux[4] != 0.0


@njit(cache=True)
def step_poses(
    off_rot: NDArray[np.float64], off_av: NDArray[np.float64], off_pos: NDArray[np.float64], off_vel: NDArray[np.float64],
    chars: NDArray[np.int64], reals: NDArray[np.float64], switches: NDArray[np.int64], sw_av: NDArray[np.float64], sw_lin: NDArray[np.float64],
    store_rot: NDArray[np.float64], store_aux: NDArray[np.float64], y: float, dt: float, eydt: float,
    out_rot: NDArray[np.float64], out_av: NDArray[np.float64], out_pos: NDArray[np.float64], out_vel: NDArray[np.float64],
    out_local: NDArray[np.float64], out_pelvis: NDArray[np.float64], out_contacts: NDArray[np.bool_],
) -> None:
    """One inertialized frame for N characters, writing the ``out_*`` arrays.

    Database frames come from a store of all frames (global frame index g): ``store_rot``
    (G,22,3,3) local rotations with joint 0 in the character frame, ``store_aux`` (G,5) pelvis
    (character frame) and left / right foot contacts (0 / 1).
    off_* (N,22,3) / (N,3): offsets before this frame. ``chars`` (N,2): the output frame's g
    and -1, or the row of ``switches`` (S,2: source g, destination g) of a character that
    switches this frame, whose offsets first become ``transition_offsets`` /
    ``transition_offsets_linear`` of the two frames (with velocities ``sw_av`` (2,S,22,3) and
    ``sw_lin`` (2,S,3), source then destination). Then the spring decays (``decay_spring``:
    y = ln2 / halflife, eydt = exp(-y dt)), and the pose is ``exp(offset) @ frame`` with joint
    0 turned to the heading and the pelvis (frame + offset, plus the seat correction) placed on
    the root; ``reals`` (N,4): heading, root x, root y, seat correction (as ``MotionMatcher``)."""
    n, nj = off_rot.shape[0], off_rot.shape[1]
    e = np.empty((3, 3))
    a = np.empty((3, 3))
    b = np.empty((3, 3))
    rv = np.empty(3)
    x = np.empty((nj, 3))
    v = np.empty((nj, 3))
    xp = np.empty(3)
    vp = np.empty(3)
    for i in range(n):
        g, s = chars[i, 0], chars[i, 1]
        if s >= 0:
            gs, gd = switches[s, 0], switches[s, 1]
            for j in range(nj):
                _rotvec_to_matrix(off_rot[i, j, 0], off_rot[i, j, 1], off_rot[i, j, 2], e)
                _matmul3(e, store_rot[gs, j], a)
                _matmul3_bt(a, store_rot[gd, j], b)
                _matrix_to_rotvec(b, rv)
                for c in range(3):
                    x[j, c] = rv[c]
                    v[j, c] = off_av[i, j, c] + sw_av[0, s, j, c] - sw_av[1, s, j, c]
            for c in range(3):
                xp[c] = off_pos[i, c] + store_aux[gs, c] - store_aux[gd, c]
                vp[c] = off_vel[i, c] + sw_lin[0, s, c] - sw_lin[1, s, c]
        else:
            for j in range(nj):
                for c in range(3):
                    x[j, c] = off_rot[i, j, c]
                    v[j, c] = off_av[i, j, c]
            for c in range(3):
                xp[c] = off_pos[i, c]
                vp[c] = off_vel[i, c]
        # decay_spring, element by element
        for j in range(nj):
            for c in range(3):
                j1 = v[j, c] + x[j, c] * y
                out_rot[i, j, c] = eydt * (x[j, c] + j1 * dt)
                out_av[i, j, c] = eydt * (v[j, c] - j1 * y * dt)
        for c in range(3):
            j1 = vp[c] + xp[c] * y
            out_pos[i, c] = eydt * (xp[c] + j1 * dt)
            out_vel[i, c] = eydt * (vp[c] - j1 * y * dt)
        # apply_rotation_offsets, then joint 0 turned by rot_z(heading)
        for j in range(nj):
            _rotvec_to_matrix(out_rot[i, j, 0], out_rot[i, j, 1], out_rot[i, j, 2], e)
            _matmul3(e, store_rot[g, j], out_local[i, j])
        _place_on_root(reals[i], store_aux[g], out_pos[i], out_local[i, 0], out_pelvis[i], out_contacts[i], a)


@njit(cache=True, inline="always")
def _fk_positions(local: NDArray[np.float64], pelvis: NDArray[np.float64], parents: NDArray[np.int64], offsets: NDArray[np.float64], t: NDArray[np.float64],
                  out: NDArray[np.float64]) -> None:
    """Joint positions (22,3) of one pose, as ``storyteller.sim.body.skeleton.forward_kinematics`` (its chain of
    4x4 products, each element an fma chain over k = 0..3). ``t`` (22,3,4) is scratch."""
    nj = local.shape[0]
    for r in range(3):
        for c in range(3):
            t[0, r, c] = local[0, r, c]
        t[0, r, 3] = pelvis[r]
    for j in range(1, nj):
        p = parents[j]
        for r in range(3):
            for c in range(3):
                acc = t[p, r, 0] * local[j, 0, c]
                acc = _fma(t[p, r, 1], local[j, 1, c], acc)
                acc = _fma(t[p, r, 2], local[j, 2, c], acc)
                t[j, r, c] = _fma(t[p, r, 3], 0.0, acc)
            acc = t[p, r, 0] * offsets[j, 0]
            acc = _fma(t[p, r, 1], offsets[j, 1], acc)
            acc = _fma(t[p, r, 2], offsets[j, 2], acc)
            t[j, r, 3] = _fma(t[p, r, 3], 1.0, acc)
    for j in range(nj):
        for r in range(3):
            out[j, r] = t[j, r, 3]


@njit(cache=True)
def fk_positions(local: NDArray[np.float64], pelvis: NDArray[np.float64], parents: NDArray[np.int64] = PARENT_INDEX,
                 offsets: NDArray[np.float64] = OFFSETS) -> NDArray[np.float64]:
    """Joint positions (K,22,3) of poses (K,22,3,3) with pelvis (K,3)."""
    out = np.empty((local.shape[0], local.shape[1], 3))
    t = np.empty((local.shape[1], 3, 4))
    for k in range(local.shape[0]):
        _fk_positions(local[k], pelvis[k], parents, offsets, t, out[k])
    return out


# Query-feature source vector per character (``assemble`` picks the layout's entries from it):
# joint positions (22*3), joint velocities (22*3), future root positions (3*2), future
# facings (3*2), target position (2), target facing (2), target height (1).
SRC_POS, SRC_VEL, SRC_FUT_POS, SRC_FUT_DIR, SRC_T_POS, SRC_T_DIR, SRC_T_H, SRC_SIZE = 0, 66, 132, 138, 144, 146, 148, 149
assert SRC_VEL == 3 * NUM_JOINTS and SRC_FUT_POS == 6 * NUM_JOINTS


# columns of ``query_features``'s per-character scalars
Q_HAS_PREV, Q_POSE_DT, Q_OLD_HEADING, Q_ROOT_X, Q_ROOT_Y, Q_HEADING, Q_HAS_TARGET, Q_TARGET_X, Q_TARGET_Y, Q_FACING, \
    Q_HEIGHT, Q_SIZE = range(12)


@njit(cache=True)
def query_features(
    cur_local: NDArray[np.float64], cur_pelvis: NDArray[np.float64], prev_local: NDArray[np.float64], prev_pelvis: NDArray[np.float64],
    fut_xy: NDArray[np.float64], fut_h: NDArray[np.float64], scalars: NDArray[np.float64], sources: NDArray[np.float64],
    parents: NDArray[np.int64], offsets: NDArray[np.float64],
) -> NDArray[np.float64]:
    """Raw query features (M,D) of M characters with an output pose, as
    ``storyteller.sim.motion.query_vectors.query_features_many`` computes them: joints of the last pose (``cur_*``)
    in the character frame of the new root / heading, joint velocities (last pose minus the one
    before (``prev_*``), over ``pose_dt``, in the frame of the old heading; zeros without a
    previous pose), and the control inputs of the query (``relative_target`` of the future
    points (M,3,2) / headings (M,3) and of the target). ``scalars`` (M, Q_SIZE): the ``Q_*``
    columns; ``sources`` (D,): the layout's entries of the SRC_* vector; ``parents`` /
    ``offsets``: the skeleton (``PARENT_INDEX``, ``OFFSETS``)."""
    m, nj = cur_local.shape[0], cur_local.shape[1]
    src = np.zeros(SRC_SIZE)
    out = np.empty((m, sources.shape[0]))
    t = np.empty((nj, 3, 4))
    jc = np.empty((nj, 3))
    jp = np.empty((nj, 3))
    for i in range(m):
        sc = scalars[i]
        rx, ry, h = sc[Q_ROOT_X], sc[Q_ROOT_Y], sc[Q_HEADING]
        _fk_positions(cur_local[i], cur_pelvis[i], parents, offsets, t, jc)
        c, s = math.cos(h), math.sin(h)
        for j in range(nj):
            dx = jc[j, 0] - rx
            dy = jc[j, 1] - ry
            src[SRC_POS + 3 * j] = c * dx + s * dy
            src[SRC_POS + 3 * j + 1] = -s * dx + c * dy
            src[SRC_POS + 3 * j + 2] = jc[j, 2]
        if sc[Q_HAS_PREV] != 0.0:
            _fk_positions(prev_local[i], prev_pelvis[i], parents, offsets, t, jp)
            co, so, pdt = math.cos(sc[Q_OLD_HEADING]), math.sin(sc[Q_OLD_HEADING]), sc[Q_POSE_DT]
            for j in range(nj):
                v0 = (jc[j, 0] - jp[j, 0]) / pdt
                v1 = (jc[j, 1] - jp[j, 1]) / pdt
                v2 = (jc[j, 2] - jp[j, 2]) / pdt
                src[SRC_VEL + 3 * j] = co * v0 + so * v1
                src[SRC_VEL + 3 * j + 1] = -so * v0 + co * v1
                src[SRC_VEL + 3 * j + 2] = v2
        else:
            for k in range(SRC_VEL, SRC_VEL + 3 * nj):
                src[k] = 0.0
        for k in range(3):
            d0 = fut_xy[i, k, 0] - rx
            d1 = fut_xy[i, k, 1] - ry
            src[SRC_FUT_POS + 2 * k] = c * d0 + s * d1
            src[SRC_FUT_POS + 2 * k + 1] = -s * d0 + c * d1
            rel = fut_h[i, k] - h
            src[SRC_FUT_DIR + 2 * k] = math.cos(rel)
            src[SRC_FUT_DIR + 2 * k + 1] = math.sin(rel)
        if sc[Q_HAS_TARGET] != 0.0:
            d0 = sc[Q_TARGET_X] - rx
            d1 = sc[Q_TARGET_Y] - ry
            src[SRC_T_POS] = c * d0 + s * d1
            src[SRC_T_POS + 1] = -s * d0 + c * d1
            rel = sc[Q_FACING] - h
            src[SRC_T_DIR] = math.cos(rel)
            src[SRC_T_DIR + 1] = math.sin(rel)
        else:
            src[SRC_T_POS] = 0.0
            src[SRC_T_POS + 1] = 0.0
            src[SRC_T_DIR] = -1.0
            src[SRC_T_DIR + 1] = 0.0
        src[SRC_T_H] = sc[Q_HEIGHT]
        for k in range(sources.shape[0]):
            out[i, k] = src[sources[k]]
    return out


@njit(cache=True)
def nearest_rows(rows_t: NDArray[np.float64], queries: NDArray[np.float64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """Exact nearest row for each query: rows_t (D,N) (the rows, transposed), queries (M,D) ->
    (row index (M,), squared distance (M,)). Distances are summed dimension by dimension in
    order (as ``storyteller.sim.motion.database.squared_distances``); ties go to the lowest row."""
    d, n = rows_t.shape
    m = queries.shape[0]
    idx = np.empty(m, dtype=np.int64)
    dist = np.empty(m)
    acc = np.empty(n)
    for q in range(m):
        acc[:] = 0.0
        for k in range(d):
            qk = queries[q, k]
            row = rows_t[k]
            for r in range(n):
                diff = row[r] - qk
                acc[r] += diff * diff
        best, bd = 0, acc[0]
        for r in range(1, n):
            if acc[r] < bd:
                best, bd = r, acc[r]
        idx[q] = best
        dist[q] = bd
    return idx, dist


@njit(cache=True)
def advance_clips(
    frame: NDArray[np.int64], clock: NDArray[np.float64], since: NDArray[np.int64], done: NDArray[np.bool_],
    cur: NDArray[np.int64], info: NDArray[np.int64], force: NDArray[np.bool_], step_frames: float, interval: int,
    base: NDArray[np.int64], nxt: NDArray[np.int64], end: NDArray[np.bool_], loops: NDArray[np.bool_],
    completes: NDArray[np.bool_], entry_key: NDArray[np.bool_],
) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_], NDArray[np.bool_],
           NDArray[np.bool_], NDArray[np.bool_]]:
    """The clip bookkeeping of one matcher step for N characters (``MotionMatcher.step_many``'s
    rules): the frame clock advances by ``step_frames``; the frame follows its clip's next-frame
    table for every whole frame passed (stopping at a non-looping end); a search is needed on a
    database change (``info`` != ``cur``, the key indices of the query's and the state's
    databases), a forced search, after ``interval`` frames and at a clip's end, except that a
    completing database (``completes``) plays a non-looping clip through.

    Frames are per database; ``base[key]`` places a database's frames in the tables ``nxt``
    (next frame, per database), ``end`` (a non-loop end) and ``loops`` (the frame's clip
    loops). Returns (frame, clock, since-search, need search, database changed, search the
    entry index, done) per character."""
    n = frame.shape[0]
    out_frame = np.empty(n, dtype=np.int64)
    out_clock = np.empty(n)
    out_since = np.empty(n, dtype=np.int64)
    need = np.empty(n, dtype=np.bool_)
    changed = np.empty(n, dtype=np.bool_)
    entry = np.empty(n, dtype=np.bool_)
    out_done = np.empty(n, dtype=np.bool_)
    for i in range(n):
        c = clock[i] + step_frames
        n_adv = math.floor(c + 1e-9)
        c -= n_adv
        b = base[cur[i]]
        f = frame[i]
        ended = False
        for _ in range(n_adv):
            if end[b + f]:
                ended = True
                break
            f = nxt[b + f]
        ch = info[i] != cur[i]
        comp = (not ch) and completes[info[i]] and not loops[b + f]
        dn = done[i] and not ch
        sn = since[i] + n_adv
        nd = ch or force[i] or (sn >= interval and not comp) or (ended and not comp)
        if ended and comp:  # completing actions play through
            dn = True
            nd = ch or force[i]
        out_frame[i] = f
        out_clock[i] = c
        out_since[i] = 0 if nd else sn
        need[i] = nd
        changed[i] = ch
        entry[i] = ch and entry_key[info[i]]
        out_done[i] = dn
    return out_frame, out_clock, out_since, need, changed, entry, out_done

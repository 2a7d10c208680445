"""Motion search benchmark: exact KD-tree vs brute force on locomotion features.

Builds locomotion databases of about 6.6k and 100k frames from procedural walking clips
(speeds 0.5-1.8 m/s, turn rates -1.2..1.2 rad/s), keeps 27 feature dimensions (the
locomotion layout without spine3 velocity), normalises them like a motion database, and
times per-query latency of brute force and of the KD-tree (single queries and a batch, as
a frame of many characters would issue). Every KD answer is checked against brute force.

Run: python -m benchmark.bench_motion_search [--queries 300] [--seed 0]
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from sim.motion_database import NearestFrameIndex, clip_raw_features
from sim.procedural_locomotion import locomotion_clip, step_length


def _features(frames: int, rng: np.random.Generator) -> np.ndarray:
    rows: list[np.ndarray] = []
    total = 0
    while total < frames:
        v = float(rng.uniform(0.5, 1.8))
        w = float(rng.uniform(-1.2, 1.2))
        period = 2 * 2 * float(step_length(v)) / v
        clip = locomotion_clip("bench", lambda t, v=v: np.full_like(t, v), lambda t, w=w: np.full_like(t, w),
                               period, loops=True)
        f = clip_raw_features(clip, "locomotion")
        f = np.delete(f, np.s_[15:18], axis=1)  # 27-D: drop spine3 velocity
        rows.append(f)
        total += len(f)
    feats = np.concatenate(rows)[:frames]
    return (feats - feats.mean(axis=0)) / np.maximum(feats.std(axis=0), 1e-6)


def _time(fn, reps: int) -> float:  # type: ignore[no-untyped-def]
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    return (time.perf_counter() - t0) / reps


def bench(frames: int, n_queries: int, seed: int) -> dict[str, float]:
    rng = np.random.default_rng(seed)
    t0 = time.perf_counter()
    feats = _features(frames, rng)
    build_s = time.perf_counter() - t0
    picks = rng.integers(0, frames, n_queries)
    queries = feats[picks] + rng.normal(scale=0.15, size=(n_queries, feats.shape[1]))
    out: dict[str, float] = {"frames": frames, "dims": feats.shape[1], "generate_s": build_s}
    for leaf in (8, 16, 32):
        index = NearestFrameIndex(feats, leafsize=leaf)
        t = time.perf_counter()
        kd = [index.query(q) for q in queries]
        out[f"kd_leaf{leaf}_us"] = (time.perf_counter() - t) / n_queries * 1e6
    index = NearestFrameIndex(feats, leafsize=16)
    t = time.perf_counter()
    kd = [index.query(q) for q in queries]
    out["kd_us"] = (time.perf_counter() - t) / n_queries * 1e6
    t = time.perf_counter()
    batch_i, _ = index.query_many(queries)
    out["kd_batch_us"] = (time.perf_counter() - t) / n_queries * 1e6
    t = time.perf_counter()
    brute = [index.brute_force(q) for q in queries]
    out["brute_us"] = (time.perf_counter() - t) / n_queries * 1e6
    t = time.perf_counter()
    naive = [int(np.argmin(np.sum((feats - q) ** 2, axis=1))) for q in queries]
    out["brute_numpy_sum_us"] = (time.perf_counter() - t) / n_queries * 1e6
    mismatches = sum(a != b for a, b in zip(kd, brute, strict=True))
    mismatches += int(np.sum(batch_i != np.array([b[0] for b in brute])))
    out["mismatches"] = mismatches
    out["naive_disagreements"] = sum(a[0] != b for a, b in zip(brute, naive, strict=True))
    out["speedup"] = out["brute_us"] / out["kd_us"]
    out["speedup_batch"] = out["brute_us"] / out["kd_batch_us"]
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--queries", type=int, default=300)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    for frames in (6_600, 100_000):
        r = bench(frames, args.queries, args.seed)
        print(f"{frames:>7} frames x {r['dims']}-D (generated in {r['generate_s']:.1f} s)")
        print(f"  brute force      {r['brute_us']:9.1f} us/query  (np.sum variant {r['brute_numpy_sum_us']:.1f} us)")
        print(f"  KD-tree          {r['kd_us']:9.1f} us/query  speedup x{r['speedup']:.1f}"
              f"  (leafsize 8/16/32: {r['kd_leaf8_us']:.0f}/{r['kd_leaf16_us']:.0f}/{r['kd_leaf32_us']:.0f} us)")
        print(f"  KD-tree, batch   {r['kd_batch_us']:9.1f} us/query  speedup x{r['speedup_batch']:.1f}")
        print(f"  exact mismatches vs brute force: {r['mismatches']} of {2 * args.queries}"
              f"  (np.sum argmin differs on {r['naive_disagreements']} ties/roundings)")


if __name__ == "__main__":
    main()

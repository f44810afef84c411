"""Model cache: where ONNX files live, which public files spgeo knows, and fetching them.

The cache directory is ``$SPGEO_MODEL_DIR`` if set, else
``platformdirs.user_cache_dir("spgeo")/models``.  :data:`REGISTRY` lists
public ONNX exports with their URL, sha256 (where one is published), size,
licence and the config preset that drives them
(:data:`spgeo.frontend.onnx_sam.SAM_PRESETS`,
:data:`spgeo.frontend.onnx_normals.NORMAL_PRESETS`,
:data:`spgeo.frontend.onnx_depth.DEPTH_PRESETS`).

Downloads go to a temporary file in the cache directory with a progress bar,
are checked against the size and sha256 and then renamed into place
atomically.  An entry without a published sha256 is refused unless
``allow_unverified=True``; the hash actually downloaded is then recorded in
``<file>.sha256`` next to it.  :func:`resolve_model` also accepts a path to a
local ``.onnx`` file instead of a registry name.  Front-ends built from these
names are in :mod:`spgeo.frontend.from_cache` (this module imports no front-end).

Two ways to use a local file, not to be confused:

* :func:`register_local` installs a file *of a built-in entry* (one you
  downloaded by hand) into the cache, checked against the entry's sha256.
* :func:`register_model` records a *user model*: any local file under a new
  name with its kind and preset, in ``<model dir>/registry.json``
  (:data:`USER_REGISTRY_FILE`); the file stays where it is and its sha256 is
  recorded and re-checked whenever it is resolved.  With ``registry=None`` (the
  default), :func:`get_entry`, :func:`list_models`, :func:`model_path`,
  :func:`resolve_model` and :func:`fetch_model` see the user entries beside
  :data:`REGISTRY`; a ``registry=`` mapping given explicitly is used alone.

The ``spgeo models list|fetch|path|register`` command is :mod:`spgeo.cli.models`.
"""
from __future__ import annotations

import hashlib
import json
import logging
import re
import os
import shutil
import tempfile
import urllib.error
import urllib.request
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import List, Mapping, Optional, Tuple, Union

__all__ = [
    "ModelEntry", "REGISTRY", "ModelDownloadError", "model_dir", "list_models", "get_entry",
    "model_path", "fetch_model", "register_local", "resolve_model", "sha256_file",
    "register_model", "user_models", "USER_KINDS", "USER_REGISTRY_FILE",
]

logger = logging.getLogger(__name__)

PathLike = Union[str, os.PathLike]
KINDS = ("sam-encoder", "sam-decoder", "normals", "depth")
#: kinds a user model (:func:`register_model`) may have
USER_KINDS = ("depth", "normals")
#: the user-model registry, in :func:`model_dir`
USER_REGISTRY_FILE = "registry.json"
#: preset recorded for a user model registered without one, by kind
_DEFAULT_USER_PRESET = {"depth": "generic-depth-518", "normals": "generic-480x640"}
_USER_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._+-]*$")
_CHUNK = 1 << 20


class ModelDownloadError(ConnectionError):
    """A model file could not be downloaded (network, HTTP or I/O failure)."""


@dataclass(frozen=True)
class ModelEntry:
    """One downloadable model file.

    Attributes:
        name: registry key (``<family>-encoder`` / ``<family>-decoder`` for SAM pairs).
        kind: ``"sam-encoder"``, ``"sam-decoder"``, ``"normals"`` or ``"depth"``.
        url: download URL (``https://`` or ``file://``).
        sha256: published hex digest, or ``None`` when none is published.
        size: size in bytes if published, else ``None``.
        licence: SPDX-style licence of the weights.
        preset: name of the config preset (SAM_PRESETS / NORMAL_PRESETS / DEPTH_PRESETS).
        filename: file name in the cache (default: the URL's last component).
        source: where the URL / checksum come from.
        notes: caveats (e.g. single-mask decoder, unverified convention).
        local_path: user models (:func:`register_model`) only: the absolute path
            of the file, which is used in place (not copied into the cache);
            ``""`` for built-in entries.
    """

    name: str
    kind: str
    url: str
    sha256: Optional[str]
    size: Optional[int]
    licence: str
    preset: str
    filename: str = ""
    source: str = ""
    notes: str = ""
    local_path: str = ""

    def __post_init__(self) -> None:
        if self.kind not in KINDS:
            raise ValueError(f"ModelEntry {self.name!r}: kind must be one of {KINDS}, "
                             f"got {self.kind!r}")
        if self.sha256 is not None:
            sha = self.sha256.lower()
            if len(sha) != 64 or any(c not in "0123456789abcdef" for c in sha):
                raise ValueError(f"ModelEntry {self.name!r}: sha256 must be 64 hex digits")
            object.__setattr__(self, "sha256", sha)
        if not self.filename:
            object.__setattr__(self, "filename", self.url.rstrip("/").rsplit("/", 1)[-1])


_LABELME = "https://github.com/wkentaro/labelme/releases/download/sam-20230416/"
_ESAM = "https://github.com/labelmeai/efficient-sam/releases/download/onnx-models-20231225/"
_OSAM_SAM = ("sha256 from wkentaro/osam osam/_models/sam/_models.py (the labelme author's "
             "model registry)")
_OSAM_ESAM = "sha256 from wkentaro/osam osam/_models/efficientsam/_models.py"
_SINGLE = ("quantized export made with --return-single-mask (labelme export script): one "
           "candidate per prompt, so the 3-candidate stability/smallest rule degenerates")


_DAV2 = "https://huggingface.co/onnx-community/depth-anything-v2-small/resolve/main/onnx/"
_DAV2_NOTE = ("relative (affine-invariant) inverse depth: normals approximate "
              "(spgeo.frontend.onnx_depth)")


def _e(*args, **kw) -> ModelEntry:
    return ModelEntry(*args, **kw)


#: Known public models (read-only).  Pass your own mapping as ``registry=`` to
#: the functions below to use others.
REGISTRY: Mapping[str, ModelEntry] = MappingProxyType({e.name: e for e in [
    _e("sam-vit-b-encoder", "sam-encoder", _LABELME + "sam_vit_b_01ec64.quantized.encoder.onnx",
       "3346b9cc551c9902fbf3b203935e933592b22e042365f58321c17fc12641fd6a", 99827688,
       "Apache-2.0", "sam-labelme", source=_OSAM_SAM),
    _e("sam-vit-b-decoder", "sam-decoder", _LABELME + "sam_vit_b_01ec64.quantized.decoder.onnx",
       "edbcf1a0afaa55621fb0abe6b3db1516818b609ea9368f309746a3afc68f7613", 8743656,
       "Apache-2.0", "sam-labelme", source=_OSAM_SAM, notes=_SINGLE),
    _e("sam-vit-l-encoder", "sam-encoder", _LABELME + "sam_vit_l_0b3195.quantized.encoder.onnx",
       "f7158a4a1fe7f670ef47ea2f7f852685425c1ed6caa40f5df86cbe2b0502034f", 322569107,
       "Apache-2.0", "sam-labelme", source=_OSAM_SAM),
    _e("sam-vit-l-decoder", "sam-decoder", _LABELME + "sam_vit_l_0b3195.quantized.decoder.onnx",
       "552ebb23bf52c5e5b971ac710d1eb8dccfd88b36cc6aff881d1536d1662e6d7b", 8743680,
       "Apache-2.0", "sam-labelme", source=_OSAM_SAM, notes=_SINGLE),
    _e("sam-vit-h-encoder", "sam-encoder", _LABELME + "sam_vit_h_4b8939.quantized.encoder.onnx",
       "a5c745fd4279efc5e5436b412200e983dafc2249ce172af6cc0002a71bb5f485", 656243518,
       "Apache-2.0", "sam-labelme", source=_OSAM_SAM,
       notes="ViT-H is the encoder the SuperPrimitive authors used"),
    _e("sam-vit-h-decoder", "sam-decoder", _LABELME + "sam_vit_h_4b8939.quantized.decoder.onnx",
       "020b385a45ffe51097e1acd10cd791075a86171153505f789a793bc382eef210", 8743672,
       "Apache-2.0", "sam-labelme", source=_OSAM_SAM,
       notes="single- or multi-mask export not verified; SegmentModel adapts to the "
             "candidate count it returns"),
    _e("efficientsam-vitt-encoder", "sam-encoder", _ESAM + "efficient_sam_vitt_encoder.onnx",
       "7a73ee65aa2c37237c89b4b18e73082f757ffb173899609c5d97a2bbd4ebb02d", 24799761,
       "Apache-2.0", "efficientsam", source=_OSAM_ESAM),
    _e("efficientsam-vitt-decoder", "sam-decoder", _ESAM + "efficient_sam_vitt_decoder.onnx",
       "e1afe46232c3bfa3470a6a81c7d3181836a94ea89528aff4e0f2d2c611989efd", 16565728,
       "Apache-2.0", "efficientsam", source=_OSAM_ESAM,
       notes="3 candidates per prompt, batched prompts"),
    _e("efficientsam-vits-encoder", "sam-encoder", _ESAM + "efficient_sam_vits_encoder.onnx",
       "4cacbb23c6903b1acf87f1d77ed806b840800c5fcd4ac8f650cbffed474b8896", None,
       "Apache-2.0", "efficientsam", source=_OSAM_ESAM),
    _e("efficientsam-vits-decoder", "sam-decoder", _ESAM + "efficient_sam_vits_decoder.onnx",
       "4727baf23dacfb51d4c16795b2ac382c403505556d0284e84c6ff3d4e8e36f22", None,
       "Apache-2.0", "efficientsam", source=_OSAM_ESAM,
       notes="3 candidates per prompt, batched prompts"),
    _e("metric3d-vit-small-fp16", "normals",
       "https://huggingface.co/onnx-community/metric3d-vit-small/resolve/main/onnx/"
       "model_fp16.onnx",
       "4afcc0893dbb3c0c63e270f8bb24bfa63ccf2dc68ab9c0c3601fdae4f0aafd9b", 75778144,
       "BSD-2-Clause", "metric3d-onnx", filename="metric3d-vit-small-fp16.onnx",
       source="URL from YvanYin/Metric3D README (ONNX checkpoints, issue #117); sha256/size "
              "pinned by a third-party download script, not by the publisher",
       notes="Metric3D v2 ViT-S (depth + normals); normal convention unverified"),
    _e("metric3d-vit-small", "normals",
       "https://huggingface.co/onnx-community/metric3d-vit-small/resolve/main/onnx/model.onnx",
       None, None, "BSD-2-Clause", "metric3d-onnx", filename="metric3d-vit-small.onnx",
       source="URL from YvanYin/Metric3D README (ONNX checkpoints, issue #117)",
       notes="fp32; no published sha256 (fetch needs allow_unverified); convention unverified"),
    _e("depth-anything-v2-small", "depth", _DAV2 + "model.onnx",
       "afb6a5c28f3b6bf1618c6e43f02073ef9dfdc70e937502d51603e57b0a1df10c", 99060839,
       "Apache-2.0", "depth-anything-v2", filename="depth-anything-v2-small.onnx",
       source="sha256 from the Hugging Face file page (onnx-community/depth-anything-v2-small, "
              "onnx/model.onnx, 99.1 MB); exact byte size pinned by third-party download scripts",
       notes=_DAV2_NOTE),
    _e("depth-anything-v2-small-fp16", "depth", _DAV2 + "model_fp16.onnx",
       "2df6223f206b5164e21f664ace61dabeb9bb6a49b8b5a3e00510b4807d0f5b04", 49642442,
       "Apache-2.0", "depth-anything-v2", filename="depth-anything-v2-small-fp16.onnx",
       source="sha256 / size pinned by third-party download scripts (the Hugging Face file "
              "listing shows 49.6 MB), not by the publisher",
       notes=_DAV2_NOTE + "; fp16 weights"),
]})


# ------------------------------------------------------------------ basics
def model_dir(create: bool = False) -> Path:
    """The cache directory: ``$SPGEO_MODEL_DIR`` or ``user_cache_dir("spgeo")/models``."""
    env = os.environ.get("SPGEO_MODEL_DIR")
    if env:
        path = Path(env).expanduser()
    else:
        import platformdirs

        path = Path(platformdirs.user_cache_dir("spgeo")) / "models"
    if create:
        path.mkdir(parents=True, exist_ok=True)
    return path


def _registry(registry: Optional[Mapping[str, ModelEntry]]) -> Mapping[str, ModelEntry]:
    """``registry`` when given, else :data:`REGISTRY` plus the user models."""
    if registry is not None:
        return registry
    return {**user_models(), **REGISTRY}


def get_entry(name: str, registry: Optional[Mapping[str, ModelEntry]] = None) -> ModelEntry:
    """The registry entry ``name``; ``KeyError`` listing the known names otherwise."""
    reg = _registry(registry)
    try:
        return reg[name]
    except KeyError:
        raise KeyError(f"unknown model {name!r}; known models: {sorted(reg)}") from None


def list_models(registry: Optional[Mapping[str, ModelEntry]] = None
                ) -> List[Tuple[ModelEntry, Path, bool]]:
    """``[(entry, path in the cache, present), ...]`` sorted by name."""
    reg = _registry(registry)
    out = []
    for name in sorted(reg):
        path, present = model_path(name, reg)
        out.append((reg[name], path, present))
    return out


def model_path(name: str, registry: Optional[Mapping[str, ModelEntry]] = None
               ) -> Tuple[Path, bool]:
    """``(path, present)``: where model ``name`` lives (in the cache; a user model: its
    own file) and whether the file is there (its hash is not checked here)."""
    entry = get_entry(name, registry)
    path = Path(entry.local_path) if entry.local_path else model_dir() / entry.filename
    return path, path.is_file()


def sha256_file(path: PathLike) -> str:
    """Hex sha256 of a file."""
    digest = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(_CHUNK), b""):
            digest.update(block)
    return digest.hexdigest()


def _record_hash(path: Path, sha: str) -> None:
    path.with_name(path.name + ".sha256").write_text(f"{sha}  {path.name}\n", encoding="utf-8")


# ------------------------------------------------------------------ user models
def _user_registry_path() -> Path:
    return model_dir() / USER_REGISTRY_FILE


def _user_entry(name: str, record: Mapping, where: Path) -> ModelEntry:
    """A :class:`ModelEntry` from one ``registry.json`` record (``ValueError`` naming ``where``)."""
    try:
        path = Path(record["path"])
        return ModelEntry(name, record["kind"], path.as_uri(), record["sha256"],
                          int(record["size"]), record.get("licence", "unknown"),
                          record["preset"], filename=path.name,
                          source=f"user model ({where})", notes=record.get("notes", ""),
                          local_path=str(path))
    except (KeyError, TypeError, ValueError) as exc:
        raise ValueError(f"{where}: bad record for user model {name!r}: {exc}") from exc


def user_models() -> Mapping[str, ModelEntry]:
    """The user models recorded by :func:`register_model` in ``<model dir>/registry.json``
    (empty when the file does not exist).  ``ValueError`` naming the file when it is
    not a valid registry; a record under a built-in name is ignored with a warning."""
    where = _user_registry_path()
    if not where.is_file():
        return {}
    try:
        data = json.loads(where.read_text(encoding="utf-8"))
        records = data["models"]
        if not isinstance(records, dict):
            raise TypeError("'models' is not an object")
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{where}: not a readable spgeo user-model registry ({exc}); fix "
                         f"or delete it") from exc
    out = {}
    for name, record in records.items():
        if name in REGISTRY:
            logger.warning("%s: user model %r ignored: the name is a built-in model", where, name)
            continue
        out[name] = _user_entry(name, record, where)
    return out


def _write_user_registry(entries: Mapping[str, ModelEntry]) -> Path:
    """Write the user entries to ``registry.json`` atomically (temp file + ``os.replace``)."""
    where = model_dir(create=True) / USER_REGISTRY_FILE
    records = {e.name: {"kind": e.kind, "path": e.local_path, "sha256": e.sha256,
                        "size": e.size, "preset": e.preset, "licence": e.licence,
                        "notes": e.notes} for e in entries.values()}
    text = json.dumps({"format": "spgeo-user-models", "version": 1, "models": records},
                      indent=2, sort_keys=True) + "\n"
    fd, tmp_name = tempfile.mkstemp(prefix=f".{USER_REGISTRY_FILE}.", suffix=".part",
                                    dir=str(where.parent))
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as out:
            out.write(text)
        os.replace(tmp_name, where)
    finally:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
    return where


def register_model(name: str, path: PathLike, kind: str = "depth", preset: Optional[str] = None,
                   licence: str = "unknown", notes: str = "") -> ModelEntry:
    """Record local file ``path`` as user model ``name`` (not to be confused with
    :func:`register_local`, which installs the file of a *built-in* entry into the cache).

    The file stays where it is; its absolute path, size and sha256 are written with
    ``kind`` and ``preset`` to ``<model dir>/registry.json`` (atomically), so that
    ``name`` resolves to it wherever a model name is accepted (:func:`resolve_model`
    re-checks the sha256).  Registering a user name again replaces its record.

    Args:
        name: letters, digits and ``._+-``, starting with a letter or digit; not a
            built-in name.
        path: the model file.
        kind: one of :data:`USER_KINDS` (``"depth"`` or ``"normals"``).
        preset: config preset of that kind (``DEPTH_PRESETS`` / ``NORMAL_PRESETS`` of
            :mod:`spgeo.frontend`; not checked here, the front-end checks it when it
            builds the model).  ``None``: ``"generic-depth-518"`` for depth,
            ``"generic-480x640"`` for normals.
        licence, notes: free text kept with the record.

    Returns the new entry.  Raises ``ValueError`` for a built-in or malformed name, a
    kind outside :data:`USER_KINDS` or an unreadable ``registry.json``;
    ``FileNotFoundError`` when ``path`` is not a file.
    """
    if name in REGISTRY:
        raise ValueError(f"{name!r} is a built-in model name and cannot be registered; choose "
                         f"another name")
    if not _USER_NAME.match(name or ""):
        raise ValueError(f"bad model name {name!r}: use letters, digits and ._+- (starting "
                         f"with a letter or digit)")
    if kind not in USER_KINDS:
        raise ValueError(f"user model kind must be one of {USER_KINDS}, got {kind!r}")
    src = Path(path).expanduser()
    if not src.is_file():
        raise FileNotFoundError(f"model file not found: {src}")
    src = src.resolve()
    entries = dict(user_models())
    entries[name] = ModelEntry(
        name, kind, src.as_uri(), sha256_file(src), src.stat().st_size, licence,
        preset or _DEFAULT_USER_PRESET[kind], filename=src.name,
        source=f"user model ({_user_registry_path()})", notes=notes, local_path=str(src))
    where = _write_user_registry(entries)
    logger.info("user model %s (%s, preset %s) -> %s, recorded in %s", name, kind,
                entries[name].preset, src, where)
    return entries[name]


def _verified_user_file(entry: ModelEntry) -> Path:
    """A user model's file after checking that it exists and still has its recorded sha256."""
    path = Path(entry.local_path)
    if not path.is_file():
        raise FileNotFoundError(f"user model {entry.name!r}: file not found: {path}; register "
                                f"it again (`spgeo models register {entry.name} PATH`)")
    sha = sha256_file(path)
    if sha != entry.sha256:
        raise ValueError(f"user model {entry.name!r}: sha256 mismatch for {path}: expected "
                         f"{entry.sha256} (recorded), got {sha}; the file changed since it was "
                         f"registered (register it again if that is intended)")
    return path


# ------------------------------------------------------------------ fetch
def _open_url(url: str, timeout: float, manual: str):
    """The response of ``url``; :class:`ModelDownloadError` (saying ``manual``) without one."""
    request = urllib.request.Request(url, headers={"User-Agent": "spgeo"})
    try:
        return urllib.request.urlopen(request, timeout=timeout)
    except (urllib.error.URLError, OSError, ValueError) as exc:
        reason = getattr(exc, "reason", exc)
        raise ModelDownloadError(f"no network / could not download {url} ({reason}); "
                                 f"{manual}") from exc


def _copy_blocks(response, out, digest, bar, url: str, manual: str) -> int:
    """Copy ``response`` into ``out`` block by block, updating ``digest`` and the
    progress ``bar``; returns the number of bytes."""
    n_bytes = 0
    while True:
        try:
            block = response.read(_CHUNK)
        except OSError as exc:
            raise ModelDownloadError(f"download of {url} stopped after "
                                     f"{n_bytes} bytes ({exc}); {manual}") from exc
        if not block:
            break
        out.write(block)
        digest.update(block)
        n_bytes += len(block)
        bar.update(len(block))
    return n_bytes


def _check_download(name: str, entry: ModelEntry, n_bytes: int, digest) -> str:
    """The download's sha256; ``ValueError`` when its size or sha256 is not the entry's."""
    if entry.size is not None and n_bytes != entry.size:
        raise ValueError(f"download of {name!r} from {entry.url} has {n_bytes} bytes, "
                         f"expected {entry.size}; discarded")
    sha = digest.hexdigest()
    if entry.sha256 is not None and sha != entry.sha256:
        raise ValueError(f"sha256 mismatch for {name!r} from {entry.url}: expected "
                         f"{entry.sha256}, got {sha}; discarded")
    return sha


def fetch_model(name: str, force: bool = False, allow_unverified: bool = False,
                progress: bool = True, registry: Optional[Mapping[str, ModelEntry]] = None,
                timeout: float = 60.0) -> Path:
    """Download model ``name`` into the cache (if not already there) and return its path.

    Args:
        force: download again even if the file is present.
        allow_unverified: accept an entry without a published sha256 (the
            computed hash is recorded in ``<file>.sha256``).
        progress: show a tqdm progress bar.
        registry: mapping of entries to use instead of :data:`REGISTRY`.
        timeout: socket timeout in seconds.

    Raises:
        KeyError: unknown name.
        ValueError: no published sha256 and ``allow_unverified`` is False; or
            the download's size / sha256 does not match (the file is discarded).
        ModelDownloadError: no network / the URL could not be read; the message
            says where to place the file by hand.

    A user model (:func:`register_model`) is not downloaded: its file is checked
    (sha256) and returned.
    """
    entry = get_entry(name, registry)
    if entry.local_path:
        return _verified_user_file(entry)
    dest = model_dir() / entry.filename
    if dest.is_file() and not force:
        if entry.size is not None and dest.stat().st_size != entry.size:
            raise ValueError(f"cached {dest} has {dest.stat().st_size} bytes, expected "
                             f"{entry.size}; fetch again with force=True (--force)")
        logger.info("model %s already present at %s", name, dest)
        return dest
    if entry.sha256 is None and not allow_unverified:
        raise ValueError(f"model {name!r} has no published sha256; download it anyway with "
                         f"allow_unverified=True (CLI: --allow-unverified), or place the file at "
                         f"{dest} yourself")
    dest.parent.mkdir(parents=True, exist_ok=True)
    manual = (f"place the file at {dest} manually"
              + (f" (sha256 {entry.sha256})" if entry.sha256 else ""))
    fd, tmp_name = tempfile.mkstemp(prefix=f".{entry.filename}.", suffix=".part",
                                    dir=str(dest.parent))
    tmp = Path(tmp_name)
    digest = hashlib.sha256()
    try:
        response = _open_url(entry.url, timeout, manual)
        from tqdm import tqdm

        with response, os.fdopen(fd, "wb") as out:
            fd = -1
            total = response.headers.get("Content-Length") if response.headers else None
            total = int(total) if total and total.isdigit() else entry.size
            with tqdm(total=total, unit="B", unit_scale=True, desc=entry.filename,
                      disable=not progress) as bar:
                n_bytes = _copy_blocks(response, out, digest, bar, entry.url, manual)
        sha = _check_download(name, entry, n_bytes, digest)
        os.replace(tmp, dest)
    finally:
        if fd >= 0:
            os.close(fd)
        if tmp.exists():
            tmp.unlink()
    if entry.sha256 is None:
        logger.warning("model %s downloaded WITHOUT verification; sha256 %s recorded in %s.sha256",
                       name, sha, dest.name)
        _record_hash(dest, sha)
    logger.info("model %s installed at %s (%d bytes)", name, dest, n_bytes)
    return dest


def register_local(name: str, path: PathLike, allow_unverified: bool = False,
                   registry: Optional[Mapping[str, ModelEntry]] = None) -> Path:
    """Install a local copy of the file of registry model ``name`` (a built-in
    entry, e.g. downloaded by hand) into the cache.  To use a file of your own
    under a new name, see :func:`register_model`.

    The file is checked against the entry's sha256 (mismatch: ``ValueError``);
    entries without one need ``allow_unverified=True`` and get the computed
    hash recorded.  Returns the cache path.  ``ValueError`` for a user model.
    """
    entry = get_entry(name, registry)
    if entry.local_path:
        raise ValueError(f"{name!r} is a user model (file {entry.local_path}); use "
                         f"register_model to record another file under that name")
    src = Path(path)
    if not src.is_file():
        raise FileNotFoundError(f"model file not found: {src}")
    sha = sha256_file(src)
    if entry.sha256 is None:
        if not allow_unverified:
            raise ValueError(f"model {name!r} has no published sha256; pass allow_unverified=True")
    elif sha != entry.sha256:
        raise ValueError(f"sha256 mismatch for {name!r} ({src}): expected {entry.sha256}, "
                         f"got {sha}")
    dest = model_dir(create=True) / entry.filename
    fd, tmp_name = tempfile.mkstemp(prefix=f".{entry.filename}.", suffix=".part",
                                    dir=str(dest.parent))
    os.close(fd)
    try:
        shutil.copyfile(src, tmp_name)
        os.replace(tmp_name, dest)
    finally:
        if os.path.exists(tmp_name):
            os.unlink(tmp_name)
    if entry.sha256 is None:
        _record_hash(dest, sha)
    return dest


def resolve_model(name_or_path: PathLike, registry: Optional[Mapping[str, ModelEntry]] = None
                  ) -> Tuple[Path, Optional[ModelEntry]]:
    """A registry name or a path to a local file -> ``(path, entry or None)``.

    Registry models must already be in the cache (``FileNotFoundError`` says
    how to fetch them); nothing is downloaded here.  A user model's file is
    re-hashed: ``ValueError`` naming the file, the recorded and the actual
    sha256 when it changed, ``FileNotFoundError`` when it is gone.
    """
    text = os.fspath(name_or_path)
    reg = _registry(registry)
    if text in reg and reg[text].local_path:
        return _verified_user_file(reg[text]), reg[text]
    if text in reg:
        path, present = model_path(text, reg)
        if not present:
            raise FileNotFoundError(f"model {text!r} is not in the cache ({path}); run "
                                    f"`spgeo models fetch {text}` or spgeo.models.fetch_model")
        return path, reg[text]
    path = Path(text).expanduser()
    if path.is_file():
        return path, None
    raise FileNotFoundError(f"model file not found: {path} (and {text!r} is not a registry "
                            f"name; known: {sorted(reg)})")


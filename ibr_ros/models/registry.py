# SPDX-FileCopyrightText: the ibr_ros developers
# SPDX-License-Identifier: BSD-3-Clause
"""Well-known ONNX models that ``ibr models fetch`` downloads (sha256-verified) into a local cache.

Nothing here runs at import or at run time of the pipeline: fetching is an explicit user action
for machines with internet access. A download is streamed to a temporary file in the target folder,
its sha256 checked, then renamed into place, so an interrupted or corrupt download never leaves a
file under the final name.
"""

from __future__ import annotations

import hashlib
import os
import urllib.error
import urllib.request
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from ibr_ros.errors import UserError

__all__ = ['MODELS', 'ModelEntry', 'default_cache_dir', 'fetch_model', 'sha256_file']

CHUNK = 1 << 20


@dataclass(frozen=True)
class ModelEntry:
    """A downloadable model: documented URL, expected sha256 (hex), file name and its I/O preset.

    ``preset`` names an entry of :data:`ibr_ros.core.depth.mono.PRESETS` (depth models).
    ``sha256_source`` says where the checksum comes from.
    """

    name: str
    url: str
    sha256: str
    filename: str
    preset: str
    size_bytes: int | None = None
    license: str = ''
    sha256_source: str = ''


MODELS: dict[str, ModelEntry] = {
    e.name: e
    for e in (
        # MiDaS v2.1 small (EfficientNet-Lite3), 256x256 ONNX from the MiDaS v2_1 GitHub release.
        ModelEntry(
            name='midas_v21_small',
            url='https://github.com/isl-org/MiDaS/releases/download/v2_1/model-small.onnx',
            sha256='2d8c6cb8f415229daf1eb041024208e2608c9f98e17c81cc7c6ecb449c56fd58',
            filename='midas_v21_small_256.onnx',
            preset='midas_v21_small',
            size_bytes=66_764_249,
            license='MIT (isl-org/MiDaS)',
            sha256_source='recorded identically by two independent projects; the release page lists none',
        ),
        # Depth-Anything-V2 small, ONNX export of the onnx-community organisation.
        ModelEntry(
            name='depth_anything_v2_small',
            url='https://huggingface.co/onnx-community/depth-anything-v2-small/resolve/main/onnx/model.onnx',
            sha256='afb6a5c28f3b6bf1618c6e43f02073ef9dfdc70e937502d51603e57b0a1df10c',
            filename='depth_anything_v2_small.onnx',
            preset='depth_anything_v2',
            size_bytes=99_060_839,
            license='Apache-2.0 (depth-anything/Depth-Anything-V2-Small)',
            sha256_source='recorded by one independent project; verify against the file page (LFS sha256)',
        ),
    )
}


def default_cache_dir() -> Path:
    """``$XDG_CACHE_HOME/ibr_ros/models`` (default ``~/.cache/ibr_ros/models``)."""
    base = os.environ.get('XDG_CACHE_HOME') or str(Path.home() / '.cache')
    return Path(base) / 'ibr_ros' / 'models'


def sha256_file(path: Path) -> str:
    """Hex sha256 of a file."""
    h = hashlib.sha256()
    with open(path, 'rb') as f:
        for block in iter(lambda: f.read(CHUNK), b''):
            h.update(block)
    return h.hexdigest()


def fetch_model(
    entry: ModelEntry,
    to: Path | None = None,
    *,
    timeout_s: float = 30.0,
    progress: Callable[[int, int | None], None] | None = None,
) -> Path:
    """Download ``entry`` into folder ``to`` (default :func:`default_cache_dir`) and return its path.

    An existing file with the right sha256 is reused without downloading. Raises UserError for an
    unreachable URL (``cannot reach URL: ...``), an HTTP error, or a checksum mismatch (naming the
    expected and actual sha256; the download is deleted). ``progress(bytes_done, bytes_total)``.
    """
    folder = Path(to) if to is not None else default_cache_dir()
    folder.mkdir(parents=True, exist_ok=True)
    dest = folder / entry.filename
    expected = entry.sha256.lower()
    if dest.is_file() and sha256_file(dest) == expected:
        return dest
    tmp = folder / f'.{entry.filename}.part'
    h = hashlib.sha256()
    try:
        with urllib.request.urlopen(entry.url, timeout=timeout_s) as resp, open(tmp, 'wb') as f:
            total = resp.headers.get('Content-Length')
            total_n = int(total) if total and total.isdigit() else None
            done = 0
            for block in iter(lambda: resp.read(CHUNK), b''):
                f.write(block)
                h.update(block)
                done += len(block)
                if progress is not None:
                    progress(done, total_n)
    except urllib.error.HTTPError as exc:
        tmp.unlink(missing_ok=True)
        raise UserError(f'cannot download {entry.url}: HTTP {exc.code} {exc.reason}') from exc
    except (urllib.error.URLError, OSError, TimeoutError) as exc:
        tmp.unlink(missing_ok=True)
        reason = getattr(exc, 'reason', exc)
        raise UserError(f'cannot reach URL: {entry.url} ({reason})') from exc
    actual = h.hexdigest()
    if actual != expected:
        tmp.unlink(missing_ok=True)
        raise UserError(
            f'checksum mismatch for {entry.name} from {entry.url}: expected sha256 {expected}, got {actual}'
        )
    tmp.replace(dest)
    return dest

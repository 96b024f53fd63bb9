"""Rendered frames of the synthetic street kept on disk, for repeated runs (`VSLAM_SYNTHETIC_CACHE=DIR`).

Rendering costs ~0.08 s a full-size frame, several times what tracking it costs, so running the embedded
default again (a demo, a CI job, a test suite with many short runs in many processes) is mostly rendering
the same frames again. With the environment variable ``VSLAM_SYNTHETIC_CACHE`` naming a folder, each frame is
read from there when present and written there once rendered; without it nothing is written. The scene the
frames are rendered from (its textures and rectangles, ~1 s of CPU to build) is kept beside them, so that a
process rendering frames no other has rendered yet reads it instead of building it again (`scene_folder`).

A frame is a pure function of the renderer's code and of (route, seed, n_frames, camera height, image size,
index), so the file name holds all of them and the renderer's version is a hash of its source files: a
changed renderer never reads an older renderer's frames. Files are written to a temporary name and renamed
into place (two runs at once never see half a file); any file that cannot be read is rendered again, and a
folder that cannot be written to (read-only, full disk) only costs the time it would have saved.
"""

from __future__ import annotations

import functools
import hashlib
import os
import tempfile
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

import numpy as np

ENVIRONMENT = "VSLAM_SYNTHETIC_CACHE"


@functools.lru_cache(maxsize=1)
def renderer_version() -> str:
    """Hash of the synthetic street's source files (12 hex digits)."""
    digest = hashlib.sha1()
    for path in sorted(Path(__file__).parent.glob("*.py")):
        digest.update(path.name.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def cache_folder() -> Path | None:
    """The cache's folder for this renderer, or None when ``VSLAM_SYNTHETIC_CACHE`` is unset or empty."""
    root = os.environ.get(ENVIRONMENT)
    return Path(root) / renderer_version() if root else None


def scene_folder() -> Path | None:
    """The folder of the stored scenes (beside the frames' folder, ``scenes-VERSION``), or None when
    ``VSLAM_SYNTHETIC_CACHE`` is unset or empty."""
    frames = cache_folder()
    return frames.with_name(f"scenes-{frames.name}") if frames is not None else None


def stored_arrays(name: str, names: tuple[str, ...],
                  build: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """`build()` (arrays by name: `names`), or the same arrays read back from the stored scenes (`scene_folder`),
    where they are written once built: a process rendering frames no other has rendered yet skips building them.
    A file that cannot be read, or holds other names, is built again."""
    folder = scene_folder()
    if folder is None:
        return build()
    path = folder / f"{name}.npz"
    parts = load_arrays(path)
    if parts is None or sorted(parts) != sorted(names):
        parts = build()
        store_arrays(path, parts)
    return parts


def load_arrays(path: Path) -> dict[str, np.ndarray] | None:
    """The named arrays stored at `path` (`store_arrays`), or None when the file is missing or unreadable."""
    try:
        with np.load(path, allow_pickle=False) as stored:
            return {name: stored[name] for name in stored.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile):
        return None


def store_arrays(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write `arrays` to `path` (.npz, uncompressed) atomically; a failure (full disk, no permission) is ignored."""
    _store(path, lambda file: np.savez(file, allow_pickle=False, **arrays))


def frame_path(folder: Path, key: tuple[str, int, int, float, int, int, float], index: int) -> Path:
    """File of frame `index` of the street `key` = (route, seed, n_frames, camera height, width, height, fx):
    fx too, as two resolutions can round to the same image size."""
    route, seed, n_frames, camera_height, width, height, fx = key
    return folder / f"{route}-seed{seed}-n{n_frames}-h{camera_height!r}-{width}x{height}-f{fx!r}-{index:05d}.npy"


def load_frame(path: Path, shape: tuple[int, int]) -> np.ndarray | None:
    """The (H, W) uint8 frame stored at `path`, or None when it is missing or unreadable."""
    try:
        image = np.load(path, allow_pickle=False)
    except (OSError, ValueError, EOFError):
        return None
    return image if image.dtype == np.uint8 and image.shape == shape else None


def store_frame(path: Path, image: np.ndarray) -> None:
    """Write `image` to `path` atomically; a failure (full disk, no permission) is ignored."""
    _store(path, lambda file: np.save(file, image, allow_pickle=False))


def _store(path: Path, write: Callable[[BinaryIO], None]) -> None:
    """`write` the file to a temporary name beside `path`, then rename it into place; OSError ignored."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, prefix=".frame-", suffix=path.suffix)
        try:
            with os.fdopen(handle, "wb") as file:
                write(file)
            os.replace(temporary, path)
        except BaseException:
            Path(temporary).unlink(missing_ok=True)
            raise
    except OSError:
        pass

"""Where numba keeps the package's compiled kernels: a folder per version of the source.

numba invalidates a cached kernel when the file that defines it changes, not when a kernel it
calls does: `tof_device._targets_kernel` calls `sensor.cluster_median`, so an edit of the
latter left the simulated device running the old rule from its cache, silently (straddling
zones reported no target until the caches were deleted). Keyed by a hash of every source file
of the package, the cache starts cold after any edit and is never stale. It is set when the
package is imported, before any of its modules imports numba; a NUMBA_CACHE_DIR already in the
environment, or numba imported first, is left alone.
"""

from __future__ import annotations

import hashlib
import os
import sys
from pathlib import Path


def source_hash(package: Path) -> str:
    """12 hex digits of the SHA-1 of every .py file under `package` (path and contents)."""
    digest = hashlib.sha1()
    for path in sorted(package.rglob("*.py")):
        digest.update(path.relative_to(package).as_posix().encode())
        digest.update(b"\0")
        digest.update(path.read_bytes())
    return digest.hexdigest()[:12]


def cache_dir(package: Path) -> Path:
    """The cache folder for the package's current source: in its __pycache__ (ignored by git,
    removed with it), or under ~/.cache when the package folder is not writable."""
    root = (package / "__pycache__" if os.access(package, os.W_OK)
            else Path.home() / ".cache" / "lrnbv_drake")
    return root / f"numba-{source_hash(package)}"


def use_versioned_cache() -> None:
    """Points numba's cache at `cache_dir` unless numba is imported or a cache is chosen."""
    if "numba" not in sys.modules and "NUMBA_CACHE_DIR" not in os.environ:
        os.environ["NUMBA_CACHE_DIR"] = str(cache_dir(Path(__file__).parent))

"""Keep numba's on-disk cache consistent with the sources of the twin's kernels.

numba keys a cached function by its own file only: after an edit to a callee in another file
(say ``idm.py``), a caller cached from ``engine.py`` would keep running the old callee's code.
:func:`drop_stale_numba_cache` hashes every source the kernels are compiled from and deletes the
numba cache files of those packages when the hash changed since the last import. It handles
numba's default cache location (``__pycache__`` next to the sources); with ``NUMBA_CACHE_DIR`` set,
clear that directory yourself after editing kernels.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

_PACKAGE_ROOT = Path(__file__).resolve().parents[1]
KERNEL_SOURCE_DIRS = (_PACKAGE_ROOT / "sim", _PACKAGE_ROOT / "scenario", _PACKAGE_ROOT / "mpc")
"""Packages whose modules define numba kernels (the twin calls the scenario's observation,
safety-index and reward kernels; the planner's compiled step calls the twin's)."""
STAMP_NAME = "numba_sources.sha256"


def sources_digest() -> str:
    """SHA-256 over the paths and contents of every ``.py`` file in :data:`KERNEL_SOURCE_DIRS` and their
    subpackages (``srmpc/mpc/problem``, ``solvers``, ``nmpc``)."""
    digest = hashlib.sha256()
    for directory in KERNEL_SOURCE_DIRS:
        for path in sorted(directory.rglob("*.py")):
            digest.update(path.relative_to(_PACKAGE_ROOT).as_posix().encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def drop_stale_numba_cache() -> bool:
    """Delete the packages' numba cache files if the sources changed; return whether it did."""
    stamp = KERNEL_SOURCE_DIRS[0] / "__pycache__" / STAMP_NAME
    current = sources_digest()
    try:
        if stamp.read_text().strip() == current:
            return False
    except OSError:
        pass
    for directory in KERNEL_SOURCE_DIRS:
        for pattern in ("*.nbi", "*.nbc"):
            for cached in directory.rglob(f"__pycache__/{pattern}"):
                cached.unlink(missing_ok=True)
    try:
        stamp.parent.mkdir(exist_ok=True)
        stamp.write_text(current + "\n")
    except OSError:  # read-only install: numba falls back to its own cache rules
        pass
    return True

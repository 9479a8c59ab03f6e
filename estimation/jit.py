"""Compilation options shared by every numba kernel of fourwis, and an on-disk cache that
follows the code.

numba's cache (``cache=True``) is invalidated only when the source file of the cached
function itself changes, not when a function it calls from another module does (numba
documentation, "Notes on caching"). fourwis's kernels call across modules (the estimators in
``joint.py`` inline ``model.py`` and ``ckf.py``; the plant in ``vehicle.py`` inlines
``tyre.py``), so an edit to the tyre or estimation model would otherwise leave stale compiled
code in use, silently. Importing this module therefore points numba's cache at
``<checkout>/.numba_cache/<fingerprint>``, the fingerprint hashing the source of every module
with compiled kernels: after any edit to one of them everything compiles afresh once (~45 s),
and switching back to an earlier version finds its cache again. A ``NUMBA_CACHE_DIR`` set by
the user is left as it is (and with it numba's own invalidation rule). Delete
``.numba_cache/`` to reclaim the disk space of old versions (~15 MB each).

Every kernel module imports :data:`JIT` from here, so the cache directory is set before its
first decorator runs. The setting is numba's process-wide ``config.CACHE_DIR``.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numba

#: options of every fourwis kernel: cached on disk, NumPy's floating-point error semantics
#: (division by zero gives inf/nan instead of raising, as in vectorised NumPy code)
JIT = dict(cache=True, error_model="numpy")

ROOT = Path(__file__).resolve().parent.parent  #: the checkout (or site-packages) holding the packages
PACKAGES = ("envs", "estimation", "control")  #: where compiled kernels live


def kernel_fingerprint(root: Path = ROOT, packages: tuple[str, ...] = PACKAGES) -> str:
    """16 hex digits hashing the path and source of every ``.py`` file under ``root/packages``
    that uses numba (a file mentioning ``numba``); other files do not affect it."""
    digest = hashlib.sha256()
    for package in packages:
        for path in sorted((root / package).glob("*.py")):
            source = path.read_bytes()
            if b"numba" in source:
                digest.update(path.relative_to(root).as_posix().encode() + b"\0" + source + b"\0")
    return digest.hexdigest()[:16]


if not numba.config.CACHE_DIR:
    numba.config.CACHE_DIR = str(ROOT / ".numba_cache" / kernel_fingerprint())

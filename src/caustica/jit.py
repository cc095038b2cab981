"""The one place that decides how caustica's kernels are compiled.

Every Numba kernel in the package is decorated with :func:`kernel` (serial,
inlinable device code) or :func:`parallel_kernel` (a ``prange`` loop over
independent work items).  Keeping the flags here means the caching policy can be
changed, measured and documented once.

Caching policy
--------------
* Serial kernels are cached on disk (``cache=True``) unless the environment
  variable ``CAUSTICA_NO_CACHE=1`` is set: they are the bulk of the compile time.
* Numba invalidates a cached function only when *its own* file changes, not when
  a kernel it calls changes in another file (numba #1833): a stale cache would
  silently run old code.  So the cache lives in a folder named after a hash of
  every source file of the package (``~/.cache/caustica/numba/<hash>``, or under
  ``$CAUSTICA_CACHE_DIR``): any edit, upgrade or checkout starts a fresh cache.
  A ``NUMBA_CACHE_DIR`` set by the user is respected as it is.
* Parallel kernels are never cached: caching ``parallel=True`` functions has
  crashed other projects (numba issues #7518 and #8578) and they compile
  quickly once their serial callees are cached.
* ``fastmath`` is off: photon-map estimates and Fresnel terms must not depend on
  reassociation, and NaN checks must keep working.

``CAUSTICA_NO_CACHE=1`` turns caching off (useful when measuring cold compile time).
"""
from __future__ import annotations

import hashlib
import os
from pathlib import Path

import numba
from numba import njit

CACHE_SERIAL = os.environ.get("CAUSTICA_NO_CACHE", "0") != "1"


def source_hash() -> str:
    """A short hash of every .py file of the package: the cache's version."""
    h = hashlib.sha1()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()[:16]


def _configure_cache_dir() -> None:
    if not CACHE_SERIAL or os.environ.get("NUMBA_CACHE_DIR"):
        return
    base = os.environ.get("CAUSTICA_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "caustica", "numba")
    numba.config.CACHE_DIR = os.path.join(base, source_hash())


_configure_cache_dir()


def kernel(fn=None, *, inline: bool = False):
    """Compile a serial kernel or device function (cached per CACHE_SERIAL)."""
    def wrap(f):
        return njit(cache=CACHE_SERIAL, fastmath=False, error_model="numpy",
                    inline="always" if inline else "never")(f)
    return wrap(fn) if fn is not None else wrap


def parallel_kernel(fn=None):
    """Compile a kernel whose outer loop is a ``prange`` (never cached, see module doc)."""
    def wrap(f):
        return njit(parallel=True, cache=False, fastmath=False, error_model="numpy")(f)
    return wrap(fn) if fn is not None else wrap

"""Memory guards: estimate a large allocation before making it, refuse it in one line if it cannot fit.

The limit is what this process may still use: the memory the kernel reports available
(``MemAvailable``) and the room left under the process's own limits (``RLIMIT_AS`` above its
virtual size, ``RLIMIT_DATA`` above its data size), whichever is least. ``BODYSCAN_MEMORY_LIMIT_MB``
overrides it (a number of MiB; ``0`` or ``off`` switches the guards off).
"""

from __future__ import annotations

import os

#: Environment variable overriding the limit, MiB.
ENV = "BODYSCAN_MEMORY_LIMIT_MB"
MB = 2 ** 20


class ResourceError(ValueError):
    """A request that would need more memory than the process may use (a user error)."""


def _proc_kb(path: str, key: str) -> int | None:
    try:
        with open(path) as fh:
            for line in fh:
                if line.startswith(key + ":"):
                    return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        pass
    return None


def memory_limit() -> tuple[int | None, str]:
    """(bytes this process may still allocate, where that limit comes from); None: no limit known."""
    text = os.environ.get(ENV, "").strip().lower()
    if text:
        if text in ("0", "off", "none"):
            return None, f"{ENV}={text}"
        try:
            return int(float(text) * MB), f"{ENV}={text}"
        except ValueError:
            pass
    limits = []
    available = _proc_kb("/proc/meminfo", "MemAvailable")
    if available is not None:
        limits.append((available, "memory available on this machine"))
    try:
        import resource

        for name, what, key in (("RLIMIT_AS", "address-space limit (ulimit -v)", "VmSize"),
                                ("RLIMIT_DATA", "data limit (ulimit -d)", "VmData")):
            soft = resource.getrlimit(getattr(resource, name))[0]
            if soft != resource.RLIM_INFINITY and soft > 0:
                used = _proc_kb("/proc/self/status", key) or 0
                limits.append((max(0, soft - used), f"room left under the {what}"))
    except (ImportError, OSError, ValueError, AttributeError):
        pass
    if not limits:
        return None, "no limit known"
    return min(limits)


def require_memory(nbytes: float, what: str, how: str, error=ResourceError) -> None:
    """Raise ``error`` when ``nbytes`` exceed what this process may still allocate.

    Parameters
    ----------
    nbytes : float
        Estimated peak of the allocation, bytes.
    what : str
        What needs it (``"2 heads x 69,000,000 camera rays"``).
    how : str
        How to ask for less (``"use a coarser --resolution"``).
    """
    limit, source = memory_limit()
    if limit is None or nbytes <= limit:
        return
    raise error(f"{what} would need about {nbytes / MB:,.0f} MiB, more than the {limit / MB:,.0f} MiB "
                f"this process may use ({source}); {how}, or set {ENV} to override")

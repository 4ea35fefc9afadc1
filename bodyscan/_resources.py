"""Memory guards: estimate a large allocation before making it, refuse it in one line if it cannot fit.

The limit is what this process may still use: the memory the kernel reports available
(``MemAvailable``), the room left in its control group (a container's limit, which
``MemAvailable`` does not see: cgroup v2 ``memory.max`` or v1 ``memory.limit_in_bytes``, less
what the group uses apart from reclaimable page cache) and the room left under the process's own
limits (``RLIMIT_AS`` above its virtual size, ``RLIMIT_DATA`` above its data size), whichever is
least. ``BODYSCAN_MEMORY_LIMIT_MB``
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


#: A cgroup limit at or above this many bytes means "no limit" (v1 writes 2**63 rounded to pages).
UNLIMITED = 2 ** 60


def _read_int(path: str) -> int | None:
    try:
        with open(path) as fh:
            text = fh.read().strip()
    except OSError:
        return None
    try:
        return int(text)
    except ValueError:          # cgroup v2 writes "max" for no limit
        return None


def _stat(path: str, key: str) -> int:
    try:
        with open(path) as fh:
            for line in fh:
                name, _, value = line.partition(" ")
                if name == key:
                    return int(value)
    except (OSError, ValueError):
        pass
    return 0


def cgroup_room(root: str = "/sys/fs/cgroup", proc: str = "/proc/self/cgroup") -> int | None:
    """Bytes left under the tightest memory limit of this process's control groups; None: no limit.

    Walks from the process's own group up to the root (cgroup v2), or reads the v1 memory
    controller; a group's room is its limit less its usage, page cache that can be reclaimed
    (``inactive_file``) counted as room.
    """
    rooms = []
    try:
        with open(proc) as fh:
            lines = fh.read().splitlines()
    except OSError:
        lines = []
    for line in lines:
        hierarchy, _, rest = line.partition(":")
        controllers, _, path = rest.partition(":")
        if hierarchy == "0" and controllers == "":                       # cgroup v2
            base, files = root, ("memory.max", "memory.current", "memory.stat", "inactive_file")
        elif "memory" in controllers.split(","):                         # cgroup v1
            base, files = os.path.join(root, "memory"), ("memory.limit_in_bytes", "memory.usage_in_bytes",
                                                         "memory.stat", "total_inactive_file")
        else:
            continue
        parts = [p for p in path.split("/") if p and p != ".."]
        # inside a container the group's own path is often not mounted: try it, then its parents
        for depth in range(len(parts), -1, -1):
            folder = os.path.join(base, *parts[:depth])
            limit = _read_int(os.path.join(folder, files[0]))
            if limit is None or limit >= UNLIMITED:
                continue
            used = _read_int(os.path.join(folder, files[1])) or 0
            cache = _stat(os.path.join(folder, files[2]), files[3])
            rooms.append(max(0, limit - max(0, used - cache)))
    return min(rooms) if rooms else None


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
    room = cgroup_room()
    if room is not None:
        limits.append((room, "room left under this container's memory limit (cgroup)"))
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

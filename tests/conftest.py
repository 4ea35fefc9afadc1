"""Test-wide settings."""

import os

# Every test runs under a fixed memory budget for the guards (bodyscan._resources): a test that asks
# for too much is refused the same way on every machine, and a machine whose limit the guards cannot
# read never lets a test really try a multi-gigabyte allocation (a CI run was killed that way).
# The suite's largest legitimate allocations are well under this.
os.environ.setdefault("BODYSCAN_MEMORY_LIMIT_MB", "6000")

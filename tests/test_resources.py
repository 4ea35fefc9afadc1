"""Memory guards: the limit a process may use, read from the kernel, its control group and rlimits."""

import pytest

from bodyscan import _resources
from bodyscan._resources import ResourceError, cgroup_room, memory_limit, require_memory

GB = 2 ** 30


def _tree(tmp_path, proc_line, files):
    root = tmp_path / "cg"
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    proc = tmp_path / "cgroup"
    proc.write_text(proc_line + "\n")
    return str(root), str(proc)


def test_cgroup_v2_limit_less_usage_plus_reclaimable_cache(tmp_path):
    root, proc = _tree(tmp_path, "0::/ci/job", {
        "ci/job/memory.max": str(8 * GB), "ci/job/memory.current": str(3 * GB),
        "ci/job/memory.stat": f"anon 100\ninactive_file {GB}\n",
        "ci/memory.max": "max", "memory.max": "max"})
    assert cgroup_room(root, proc) == 8 * GB - (3 * GB - GB)


def test_cgroup_v2_tightest_of_the_group_and_its_parents(tmp_path):
    root, proc = _tree(tmp_path, "0::/ci/job", {
        "ci/job/memory.max": str(16 * GB), "ci/job/memory.current": str(GB),
        "ci/memory.max": str(4 * GB), "ci/memory.current": str(3 * GB)})
    assert cgroup_room(root, proc) == GB


def test_cgroup_v1_container_sees_its_own_group_at_the_mount(tmp_path):
    # the host path in /proc/self/cgroup is not mounted inside the container: the mount is the group
    root, proc = _tree(tmp_path, "4:memory:/docker/abc", {
        "memory/memory.limit_in_bytes": str(2 * GB), "memory/memory.usage_in_bytes": str(GB // 2),
        "memory/memory.stat": f"cache 5\ntotal_inactive_file {GB // 4}\n"})
    assert cgroup_room(root, proc) == 2 * GB - GB // 4


def test_no_cgroup_limit(tmp_path):
    root, proc = _tree(tmp_path, "4:memory:/", {"memory/memory.limit_in_bytes": "9223372036854771712"})
    assert cgroup_room(root, proc) is None
    assert cgroup_room(str(tmp_path / "none"), str(tmp_path / "none")) is None


def test_cgroup_room_bounds_the_limit(monkeypatch):
    monkeypatch.delenv(_resources.ENV, raising=False)
    monkeypatch.setattr(_resources, "cgroup_room", lambda: 123 * _resources.MB)
    limit, source = memory_limit()
    assert limit == 123 * _resources.MB and "cgroup" in source
    with pytest.raises(ResourceError, match="about 200 MiB, more than the 123 MiB"):
        require_memory(200 * _resources.MB, "a test", "ask for less")
    require_memory(100 * _resources.MB, "a test", "ask for less")


def test_environment_overrides(monkeypatch):
    monkeypatch.setenv(_resources.ENV, "50")
    assert memory_limit()[0] == 50 * _resources.MB
    monkeypatch.setenv(_resources.ENV, "off")
    assert memory_limit()[0] is None
    require_memory(1e18, "anything", "nothing")

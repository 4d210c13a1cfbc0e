"""Atomic writes (a3d.runtime.io.atomic): the old file or the new one, never a partial one."""

from __future__ import annotations

import pytest

from a3d.runtime.io.atomic import atomic_write, atomic_write_bytes, remove_stale_temporaries


def test_a_failed_write_keeps_the_old_file_and_leaves_no_temporary(tmp_path) -> None:
    path = tmp_path / "a.bin"
    atomic_write_bytes(path, b"old")

    def fail_halfway(f) -> None:
        f.write(b"new, half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(path, fail_halfway, durable=True)
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["a.bin"]


def test_a_durable_write_replaces_and_stale_temporaries_of_that_file_only_are_removed(tmp_path) -> None:
    path = tmp_path / "sub" / "a.bin"
    atomic_write_bytes(path, b"one", durable=True)
    atomic_write(path, lambda f: f.write(b"two"))
    assert path.read_bytes() == b"two"
    (path.parent / ".a.bin.tmp-123-deadbeef").write_bytes(b"left by a killed writer")
    (path.parent / ".b.bin.tmp-123-deadbeef").write_bytes(b"another file's writer")
    remove_stale_temporaries(path)
    assert sorted(p.name for p in path.parent.iterdir()) == [".b.bin.tmp-123-deadbeef", "a.bin"]

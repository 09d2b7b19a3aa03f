"""Outputs are whole or absent: the temporary file is renamed into place only after a clean write."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
from frictionwatch.service.output_files import atomic_output, atomic_write_text, check_output_path


def test_clean_write_lands_whole_with_lf_endings(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "out.csv"
    with atomic_output(target) as fh:
        fh.write("a,b\n1,2\n")
    assert target.read_bytes() == b"a,b\n1,2\n"
    assert [p.name for p in target.parent.iterdir()] == ["out.csv"]
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask  # what open() would give, not mkstemp's private 0600
    target.chmod(0o640)
    atomic_write_text(target, "again")
    assert target.stat().st_mode & 0o777 == 0o640  # a replaced file keeps its mode


def test_interrupted_write_leaves_nothing_and_keeps_the_old_file(tmp_path: Path) -> None:
    target = tmp_path / "out.json"
    atomic_write_text(target, "old")
    with pytest.raises(KeyboardInterrupt):
        with atomic_output(target) as fh:
            fh.write("half")
            raise KeyboardInterrupt
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_disk_full_during_write_leaves_nothing(tmp_path: Path) -> None:
    target = tmp_path / "out.bin"
    with pytest.raises(OSError):
        with atomic_output(target, "wb") as fh:
            fh.write(b"x" * 10)
            raise OSError(28, "No space left on device")
    assert list(tmp_path.iterdir()) == []


def test_unwritable_targets_are_found_before_writing(tmp_path: Path) -> None:
    with pytest.raises(IsADirectoryError, match="is a folder"):
        check_output_path(tmp_path)
    if os.geteuid() == 0:
        pytest.skip("root writes into read-only folders")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o500)
    try:
        with pytest.raises(PermissionError, match="not writable"):
            check_output_path(ro / "out.csv")
    finally:
        ro.chmod(0o700)

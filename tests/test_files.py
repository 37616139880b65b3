"""Atomic writes (superex_deploy.files): the whole file or the previous one, never a temporary left behind."""

import pytest

from superex_deploy.files import write_atomically


def test_text_bytes_and_a_writer_land_whole_and_leave_no_temporary(tmp_path):
    path = tmp_path / "out.json"
    assert write_atomically(path, '{"a": 1}') == path and path.read_text() == '{"a": 1}'
    write_atomically(str(path), b"\x00\x01")
    assert path.read_bytes() == b"\x00\x01"
    write_atomically(path, lambda part: part.write_text("written by a function"))
    assert path.read_text() == "written by a function"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["out.json"]


def test_a_failed_write_keeps_the_previous_file(tmp_path):
    path = tmp_path / "out.txt"
    write_atomically(path, "before")

    def fails(part):
        part.write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError, match="disk full"):
        write_atomically(path, fails)
    assert path.read_text() == "before" and sorted(p.name for p in tmp_path.iterdir()) == ["out.txt"]

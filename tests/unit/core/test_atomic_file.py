"""scenenav.core.formats.atomic_file: a file is replaced whole or left as it was."""

from __future__ import annotations

import json
import threading

import pytest

from scenenav.core.formats.atomic_file import replace_atomic, write_atomic


def test_write_replaces_the_file_and_leaves_no_temporary(tmp_path):
    f = tmp_path / "pids.json"
    write_atomic(f, '{"a": 1}')
    write_atomic(f, '{"a": 1, "b": 2}')
    assert json.loads(f.read_text()) == {"a": 1, "b": 2}
    assert [p.name for p in tmp_path.iterdir()] == ["pids.json"]


def test_a_failing_writer_keeps_the_old_file_and_removes_its_temporary(tmp_path):
    f = tmp_path / "summary.json"
    write_atomic(f, "old")

    def half_then_fail(tmp):
        tmp.write_text("half")
        raise OSError(28, "No space left on device")

    with pytest.raises(OSError):
        replace_atomic(f, half_then_fail)
    assert f.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["summary.json"]


def test_a_reader_never_sees_a_partial_file(tmp_path):
    """The launcher rewrites logs/pids.json at every child it starts while tests and benchmarks
    read it; every read must parse and hold every key written before it."""
    f = tmp_path / "pids.json"
    write_atomic(f, json.dumps({"sim": 1}))
    done = threading.Event()
    bad: list[str] = []

    def reader():
        while not done.is_set():
            text = f.read_text()
            try:
                if "sim" not in json.loads(text):
                    bad.append(text)
            except ValueError:
                bad.append(text)

    t = threading.Thread(target=reader)
    t.start()
    try:
        for i in range(2000):
            write_atomic(f, json.dumps({"sim": 1, **{f"n{j}": j for j in range(i % 50)}}))
    finally:
        done.set()
        t.join()
    assert bad == []

"""``preflight.checked_once``: a file that passed its reader is not read again until the file or the
reader's source changes; a file that failed is read every time."""

import pytest

from scenenav.app.preflight import checked_once
from scenenav.core.errors import UserError


@pytest.fixture
def cache(tmp_path, monkeypatch):
    monkeypatch.setenv("SCENENAV_CACHE_DIR", str(tmp_path / "cache"))
    return tmp_path / "cache"


def test_a_passed_file_is_checked_once_until_it_changes(tmp_path, cache):
    f = tmp_path / "w.pt"
    f.write_bytes(b"weights v1")
    seen = []
    checked_once("scenenav.app.preflight", str(f), seen.append)
    checked_once("scenenav.app.preflight", str(f), seen.append)
    assert seen == [str(f)]
    assert len(list((cache / "checked").iterdir())) == 1
    checked_once("scenenav.core.errors", str(f), seen.append)      # another reader: checked again
    assert len(seen) == 2
    f.write_bytes(b"weights v2")
    checked_once("scenenav.app.preflight", str(f), seen.append)
    assert len(seen) == 3


def test_a_failing_file_is_checked_every_time(tmp_path, cache):
    f = tmp_path / "bad.pt"
    f.write_bytes(b"garbage")
    calls = []

    def bad(path):
        calls.append(path)
        raise UserError(f"{path}: not a weights file")
    for _ in range(2):
        with pytest.raises(UserError, match="not a weights file"):
            checked_once("scenenav.app.preflight", str(f), bad)
    assert len(calls) == 2 and not (cache / "checked").exists()


def test_a_missing_file_goes_to_the_reader(tmp_path, cache):
    calls = []
    checked_once("scenenav.app.preflight", str(tmp_path / "none.pt"), calls.append)
    assert calls == [str(tmp_path / "none.pt")]

"""read_bounded: a regular file only, and never more bytes than its limit."""

from __future__ import annotations

import os

import pytest

import ilcpmac.core.files
from ilcpmac.core.errors import ConfigError
from ilcpmac.core.files import read_bounded


def test_a_regular_file_within_the_limit_is_read_whole(tmp_path):
    path = tmp_path / "f.txt"
    path.write_bytes(b"x" * 100)
    assert read_bounded(path, 100, ConfigError) == b"x" * 100


def test_a_file_beyond_the_limit_is_refused_before_a_byte_is_read(tmp_path, monkeypatch):
    """A sparse file of 1 GiB against a limit of 1 MiB: refused on its size, the file never read."""
    path = tmp_path / "big.csv"
    with open(path, "wb") as f:
        f.truncate(1 << 30)

    def no_read(*args, **kwargs):
        raise AssertionError("read a file refused on its size")

    monkeypatch.setattr(ilcpmac.core.files, "open", no_read, raising=False)
    with pytest.raises(ConfigError, match=rf"^{path}: more than {1 << 20} bytes \(refused\)$"):
        read_bounded(path, 1 << 20, ConfigError)


@pytest.mark.parametrize("kind", ["fifo", "folder", "missing"])
def test_anything_but_a_regular_file_is_refused_without_blocking(tmp_path, kind):
    path = tmp_path / "x"
    if kind == "fifo":
        os.mkfifo(path)  # nobody writes it: a blocking open would hang
    elif kind == "folder":
        path.mkdir()
    expected = "no such file" if kind == "missing" else "not a regular file"
    with pytest.raises(ConfigError, match=rf"^{path}: {expected}"):
        read_bounded(path, 1 << 20, ConfigError)

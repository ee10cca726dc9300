"""Atomic writes and PNG encoding (:mod:`proctex.fileio`), each written once for the whole package."""

import io

import numpy as np
import pytest
from PIL import Image

from proctex.fileio import atomic_write, encode_png, to_uint8


def test_atomic_write_replaces_whole_and_leaves_nothing_behind(tmp_path):
    p = tmp_path / "a.json"
    assert atomic_write(p, '{"a": 1}') == p and p.read_text() == '{"a": 1}'
    atomic_write(p, b"\x00\x01")
    assert p.read_bytes() == b"\x00\x01"
    assert [q.name for q in tmp_path.iterdir()] == ["a.json"]


def test_atomic_write_failing_keeps_the_old_file_and_no_temporary(tmp_path, monkeypatch):
    import os

    p = tmp_path / "keep.txt"
    p.write_text("old")

    def broken(src, dst):
        raise OSError("disk full")

    monkeypatch.setattr(os, "replace", broken)
    with pytest.raises(OSError, match="disk full"):
        atomic_write(p, "new")
    assert p.read_text() == "old" and [q.name for q in tmp_path.iterdir()] == ["keep.txt"]
    with pytest.raises(FileNotFoundError):
        atomic_write(tmp_path / "no" / "such" / "dir.txt", "x")


def test_encode_png_round_trips_uint8_and_floats():
    rng = np.random.default_rng(0)
    img = rng.integers(0, 256, (5, 7, 3)).astype(np.uint8)
    back = np.asarray(Image.open(io.BytesIO(encode_png(img))))
    np.testing.assert_array_equal(back, img)
    rgba = rng.uniform(-0.5, 1.5, (4, 3, 4))  # floats are clipped to [0, 1] and rounded
    back = np.asarray(Image.open(io.BytesIO(encode_png(rgba))))
    np.testing.assert_array_equal(back, to_uint8(rgba))
    assert back.shape == (4, 3, 4) and to_uint8(np.array([[[0.5, 0.0, 1.0]]])).tolist() == [[[128, 0, 255]]]
    for bad in (np.zeros((4, 4)), np.zeros((4, 4, 2)), np.zeros((0, 4, 3))):
        with pytest.raises(ValueError, match="image"):
            encode_png(bad)

"""distnav.output: atomic writes leave no partial file, the rank-0 switch, JSON conversion, old import path."""

from __future__ import annotations

import json
import math
import os
import stat
from pathlib import Path

import numpy as np
import pytest

from distnav import output


class _Boom(RuntimeError):
    pass


def test_atomic_write_text_replaces_whole_file(tmp_path: Path) -> None:
    target = tmp_path / "sub" / "a.txt"
    output.atomic_write_text(target, "first\n")
    output.atomic_write_text(target, "second ü\n")
    assert target.read_bytes() == "second ü\n".encode()
    assert sorted(p.name for p in target.parent.iterdir()) == ["a.txt"]


def test_failed_write_keeps_old_file_and_leaves_no_temporary(tmp_path: Path) -> None:
    target = tmp_path / "a.json"
    output.atomic_write_json(target, {"x": 1})

    class Unserialisable:
        pass

    with pytest.raises(TypeError):
        output.atomic_write_json(target, {"x": Unserialisable()})
    assert json.loads(target.read_text()) == {"x": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.json"]


def test_failed_figure_leaves_no_file(tmp_path: Path) -> None:
    plt = output.pyplot()
    fig, _ = plt.subplots()

    def savefig(*args: object, **kwargs: object) -> None:
        Path(str(args[0])).write_bytes(b"half")
        raise _Boom("disk full")

    fig.savefig = savefig  # type: ignore[method-assign]
    with pytest.raises(_Boom):
        output.save_figure_file(fig, tmp_path / "f.png")
    assert list(tmp_path.iterdir()) == []
    assert not plt.fignum_exists(fig.number)


def test_figure_is_a_png(tmp_path: Path) -> None:
    plt = output.pyplot()
    fig, ax = plt.subplots()
    ax.plot([0, 1], [1, 0])
    output.save_figure_file(fig, tmp_path / "f.png")
    assert (tmp_path / "f.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not plt.fignum_exists(fig.number)


def test_non_writer_writes_nothing(tmp_path: Path) -> None:
    assert output.is_file_writer()
    output.set_file_writer(False)
    try:
        assert not output.is_file_writer()
        output.atomic_write_text(tmp_path / "a.txt", "x")
        output.atomic_write_json(tmp_path / "b.json", {})
        plt = output.pyplot()
        fig, _ = plt.subplots()
        output.save_figure_file(fig, tmp_path / "c.png")
        assert not plt.fignum_exists(fig.number)  # still closed
    finally:
        output.set_file_writer(True)
    assert list(tmp_path.iterdir()) == []


def test_to_jsonable() -> None:
    data = {
        1: np.array([1.5, np.nan]),
        "b": (np.int64(3), np.bool_(True)),
        "p": Path("x/y"),
        "f": np.float32(0.5),
        "inf": math.inf,
    }
    assert output.to_jsonable(data) == {"1": [1.5, None], "b": [3, True], "p": "x/y", "f": 0.5, "inf": None}


def test_experiments_reexport_pyplot_only() -> None:
    """experiments.common re-exports output's pyplot (the experiments' figure entry); the writers are imported from
    distnav.output (issue 25: one place, no second list)."""
    from distnav.experiments import common

    assert common.pyplot is output.pyplot
    assert "pyplot" in common.__all__
    assert not {"to_jsonable", "set_file_writer", "is_file_writer"} & set(common.__all__)


@pytest.mark.parametrize("mask", [0o022, 0o077, 0o002])
def test_files_follow_the_umask(tmp_path: Path, mask: int) -> None:
    old = os.umask(mask)
    try:
        output.atomic_write_text(tmp_path / "a.txt", "x")
        output.atomic_write_json(tmp_path / "b.json", {"x": 1})
        plt = output.pyplot()
        fig, _ = plt.subplots()
        output.save_figure_file(fig, tmp_path / "c.png")
        (tmp_path / "plain.txt").write_text("x")  # what open() gives: the reference
        assert os.umask(mask) == mask  # the writers put the umask back
    finally:
        os.umask(old)
    want = stat.S_IMODE((tmp_path / "plain.txt").stat().st_mode)
    assert want == 0o666 & ~mask
    for name in ("a.txt", "b.json", "c.png"):
        assert stat.S_IMODE((tmp_path / name).stat().st_mode) == want, name

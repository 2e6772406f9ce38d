"""Issue 29 item 5: under MPI only rank 0 prints progress, and a failing rank's ``error on MPI rank R of N`` line
reaches the user before the abort, also when the machine is loaded (a stress test with CPU burners)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("mpi4py", reason="the mpi extra is not installed (pip install '.[mpi]' in the clone)")

from distnav.cli import main  # noqa: E402
from test_mpi import HERE, _launch  # noqa: E402

pytestmark = pytest.mark.mpi


def _progress_lines(text: str) -> list[str]:
    return [line for line in text.splitlines() if line.lstrip().startswith(("…", "✓"))]


def test_progress_printed_by_rank_0_only(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["reproduce", "consensus", "--quick", "--out", str(tmp_path / "one")]) == 0
    alone = _progress_lines(capsys.readouterr().err)
    assert alone, "the in-process run prints progress lines"
    proc = _launch(
        ["-m", "distnav", "reproduce", "consensus", "--quick", "--backend", "mpi", "--ranks", "4"]
        + ["--out", str(tmp_path / "four")],
        timeout=300,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    lines = _progress_lines(proc.stderr)
    assert len(lines) == len(alone), f"{len(lines)} progress lines at 4 ranks, {len(alone)} alone:\n{proc.stderr}"
    assert proc.stdout.count("results: ") == 1


def test_failing_rank_error_line_under_load(tmp_path: Path) -> None:
    """Two busy loops per core compete with the four ranks; the failing rank's line must arrive every time."""
    burners = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
        for _ in range(2 * (os.cpu_count() or 1))
    ]
    try:
        for attempt in range(2):
            out = tmp_path / f"out{attempt}"
            proc = _launch([str(HERE / "mpi" / "fail_rank.py"), "2", "raise", str(out)], timeout=240)
            assert proc.returncode != 0
            assert "error on MPI rank 2 of 4: RuntimeError: injected failure" in proc.stderr, (
                f"attempt {attempt}: the error line was lost:\n{proc.stderr[-3000:]}"
            )
    finally:
        for b in burners:
            b.send_signal(signal.SIGKILL)
            b.wait(timeout=30)

"""``distnav --version`` and ``distnav --help`` start-up (issue 29 item 6: ≤ 0.3 s; they cost 1.45 CPU-s when the
CLI imported every command and solver to build its parser).

Six commands are run interleaved, ``repeat`` times each, as whole processes (``python -m distnav ...``): the
floor ``python -c pass`` (the interpreter's own start), ``--version`` and ``--help``; and, for the before/after in
one run, ``the full parser`` (``python -c`` building :func:`distnav.cli.build_parser`, what both flags and every
command paid before); and ``gnss codebias --help`` / ``reproduce consensus --help``, which now import only their own
command (issue 32 item 7), with their share of the full parser's CPU time. Figures: medians of wall seconds and of
CPU seconds (``RUSAGE_CHILDREN`` around each run: the machine's 2 cores are shared, so CPU says more than wall under
load); the ratio is to the interpreter's floor. Bytecode is
written into a fresh ``PYTHONPYCACHEPREFIX`` by one warm-up run of each command (an installed package has it).
"""

from __future__ import annotations

import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402

SRC = Path(__file__).resolve().parents[1] / "src"
GOAL_S = 0.3
COMMANDS = {
    "python -c pass (floor)": ["-c", "pass"],
    "distnav --version": ["-m", "distnav", "--version"],
    "distnav --help": ["-m", "distnav", "--help"],
    "full parser (before)": ["-c", "from distnav.cli import build_parser; build_parser()"],
    "distnav gnss codebias --help": ["-m", "distnav", "gnss", "codebias", "--help"],
    "distnav reproduce consensus --help": ["-m", "distnav", "reproduce", "consensus", "--help"],
}
#: rows held to :data:`GOAL_S`; the subcommand rows (issue 32 item 7: a command builds only its own parser, where
#: every command used to pay the full parser) are compared with the full parser's row, their "before"
GOAL_ROWS = ("distnav --version", "distnav --help")
FULL = "full parser (before)"


def _once(args: list[str], env: dict[str, str]) -> tuple[float, float]:
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    subprocess.run([sys.executable, *args], env=env, check=True, capture_output=True, timeout=300)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def run(quick: bool) -> list[dict[str, Any]]:
    repeat = 5 if quick else 15
    with tempfile.TemporaryDirectory(prefix="distnav-pycache-") as cache:
        env = {**os.environ, "PYTHONPATH": str(SRC), "PYTHONPYCACHEPREFIX": cache}
        env.pop("PYTHONDONTWRITEBYTECODE", None)
        for args in COMMANDS.values():  # warm-up: writes the stdlib's and distnav's bytecode into the prefix
            _once(args, env)
        times: dict[str, list[tuple[float, float]]] = {k: [] for k in COMMANDS}
        for _ in range(repeat):
            for name, args in COMMANDS.items():
                times[name].append(_once(args, env))
    floor_wall = np.median([w for w, _ in times["python -c pass (floor)"]])
    load = os.getloadavg()[0]
    rows = []
    for name, samples in times.items():
        wall = float(np.median([w for w, _ in samples]))
        cpu = float(np.median([c for _, c in samples]))
        timed = name in GOAL_ROWS
        full_cpu = float(np.median([c for _, c in times[FULL]]))
        rows.append(
            {
                "name": name,
                "seconds": wall,
                "cpu_seconds": cpu,
                "reference_seconds": float(floor_wall),
                "ratio": wall / float(floor_wall),
                "goal": f"≤ {GOAL_S} s" if timed else "",
                "meets_goal": (wall <= GOAL_S) if timed else None,
                "cpu_meets_goal": (cpu <= GOAL_S) if timed else None,
                "cpu_share_of_full_parser": cpu / full_cpu if full_cpu > 0 else None,
                "load_1min": load,
                "repeats": repeat,
            }
        )
    return rows


if __name__ == "__main__":
    main_for(__file__, run)

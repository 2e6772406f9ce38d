"""``distnav reproduce-all``: every paper reproduction at full size in one command, with a summary of their times.

    distnav reproduce-all --out RUN [--jobs 2] [--only NAME ...] [--quick] [--seed 0]

Runs what ``docs/claims.md`` is generated from: ``consensus``, ``admm``, ``ckf``, ``uwb`` (the paper's 50 / 50 / 100
instances), ``uwb-horizontal`` (``uwb --instances 5 --start horizontal``: the second "< 60 cm" row), ``codebias``,
``qc`` (distributed precision and data snooping: the claims table's §6 rows) and ``ckf-ionosphere``, each
``distnav reproduce NAME --out RUN/NAME`` in its own process (its output in ``RUN/NAME.log``). The longest starts
first and ``--jobs`` of them run at once; the ones that take ``--jobs`` (``uwb``, ``admm``) get it too, so the cores
stay busy to the end. ``RUN/timing.json`` and the printed table give, per reproduction, the wall time and the CPU
seconds of its process and its workers (``wait4``), with the load average over the run. Then
``python -m distnav.experiments.claims_table RUN --out docs/claims.md`` rebuilds the
table. Exit code 1 if any reproduction failed (the others still run).

The reproductions run in parallel processes, so each gets one BLAS thread (``OPENBLAS_NUM_THREADS``,
``OMP_NUM_THREADS``, ``MKL_NUM_THREADS`` = 1 unless set in the environment already; :func:`child_environment`):
their matrices are small and OpenBLAS's extra threads only compete for the same cores. Measured on 2 idle cores,
every ``results.json`` equal but the solver timings: 1,186 → 1,124 CPU-s, 10 min 4 s → 9 min 33 s.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Any

from distnav.options import add_size_option, jobs_count, output_folder, seed

__all__ = ["RUNS", "Run", "register", "run_all", "child_environment", "BLAS_THREAD_VARIABLES"]

BLAS_THREAD_VARIABLES = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def child_environment(parent: dict[str, str] | None = None) -> dict[str, str]:
    """The environment of every reproduction's process: the parent's, with one BLAS thread where the parent does not
    say otherwise (the module docstring says why)."""
    env = dict(os.environ if parent is None else parent)
    for name in BLAS_THREAD_VARIABLES:
        env.setdefault(name, "1")
    return env


@dataclass(frozen=True)
class Run:
    """One reproduction of the set: its folder name, the experiment, extra options, whether it takes ``--jobs``,
    and its CPU seconds at full size (measured; only the order matters: longest first)."""

    name: str
    experiment: str
    options: tuple[str, ...] = ()
    jobs: bool = False
    cpu_s: float = 0.0


RUNS: dict[str, Run] = {
    r.name: r
    for r in (
        Run("uwb", "uwb", jobs=True, cpu_s=1310.0),
        Run("uwb-horizontal", "uwb", ("--instances", "5", "--start", "horizontal"), jobs=True, cpu_s=130.0),
        Run("admm", "admm", jobs=True, cpu_s=52.0),
        Run("ckf-ionosphere", "ckf-ionosphere", cpu_s=18.0),
        Run("codebias", "codebias", cpu_s=13.0),
        Run("qc", "qc", cpu_s=20.0),
        Run("ckf", "ckf", cpu_s=8.0),
        Run("consensus", "consensus", cpu_s=7.5),
    )
}


@dataclass
class _Running:
    run: Run
    proc: subprocess.Popen[bytes]
    log: IO[bytes]
    t0: float = field(default_factory=time.perf_counter)


def _command(run: Run, out: Path, jobs: int, quick: bool, seed_: int) -> list[str]:
    cmd = [
        sys.executable,
        "-m",
        "distnav",
        "reproduce",
        run.experiment,
        "--out",
        str(out / run.name),
        "--seed",
        str(seed_),
        "--no-progress",
        *run.options,
    ]
    if run.jobs:
        cmd += ["--jobs", str(jobs)]
    if quick:
        cmd.append("--quick")
    return cmd


def run_all(
    names: list[str], out: Path, *, jobs: int = 2, quick: bool = False, seed_: int = 0, echo: IO[str] = sys.stdout
) -> dict[str, Any]:
    """Run the reproductions ``names`` (keys of :data:`RUNS`), longest first, ``jobs`` at a time; returns (and
    writes to ``out/timing.json``) the wall and CPU seconds of each and of the whole run."""
    out.mkdir(parents=True, exist_ok=True)
    queue = sorted((RUNS[n] for n in names), key=lambda r: -r.cpu_s)
    running: dict[int, _Running] = {}
    results: dict[str, dict[str, Any]] = {}
    loads: list[float] = [os.getloadavg()[0]]
    env = child_environment()
    t_start = time.perf_counter()
    last_sample = t_start
    while queue or running:
        while queue and len(running) < jobs:
            run = queue.pop(0)
            cmd = _command(run, out, jobs, quick, seed_)
            log = open(out / f"{run.name}.log", "wb")  # noqa: SIM115 - closed when the process ends
            proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
            running[proc.pid] = _Running(run, proc, log)
            print(f"  … {run.name}: {' '.join(cmd[2:])}", file=echo, flush=True)
        pid, status, usage = os.wait4(-1, os.WNOHANG)
        now = time.perf_counter()
        if now - last_sample >= 5.0:
            loads.append(os.getloadavg()[0])
            last_sample = now
        if pid == 0 or pid not in running:
            time.sleep(0.2)
            continue
        done = running.pop(pid)
        done.proc.returncode = os.waitstatus_to_exitcode(status)
        done.log.close()
        wall = now - done.t0
        cpu = usage.ru_utime + usage.ru_stime
        results[done.run.name] = {
            "command": _command(done.run, out, jobs, quick, seed_)[2:],
            "wall_s": wall,
            "cpu_user_s": usage.ru_utime,
            "cpu_sys_s": usage.ru_stime,
            "cpu_s": cpu,
            "returncode": done.proc.returncode,
        }
        mark = "✓" if done.proc.returncode == 0 else f"✗ (exit {done.proc.returncode}, see {done.run.name}.log)"
        print(f"  {mark} {done.run.name}: {wall:.1f} s wall, {cpu:.1f} CPU s", file=echo, flush=True)
    loads.append(os.getloadavg()[0])
    summary: dict[str, Any] = {
        "jobs": jobs,
        "quick": quick,
        "seed": seed_,
        "wall_s": time.perf_counter() - t_start,
        "blas_threads": {name: env[name] for name in BLAS_THREAD_VARIABLES},
        "cpu_s": sum(r["cpu_s"] for r in results.values()),
        "load_average_1min": {"start": loads[0], "mean": sum(loads) / len(loads), "max": max(loads)},
        "runs": {n: results[n] for n in sorted(results, key=lambda n: -results[n]["cpu_s"])},
        "failed": sorted(n for n, r in results.items() if r["returncode"] != 0),
    }
    (out / "timing.json").write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return summary


def _table(summary: dict[str, Any]) -> str:
    lines = ["| reproduction | wall [s] | CPU [s] |", "|---|---|---|"]
    for name, r in summary["runs"].items():
        lines.append(
            f"| {name} | {r['wall_s']:.1f} | {r['cpu_s']:.1f} |" + ("" if r["returncode"] == 0 else " failed |")
        )
    la = summary["load_average_1min"]
    lines.append(f"| **all** ({summary['jobs']} at a time) | {summary['wall_s']:.1f} | {summary['cpu_s']:.1f} |")
    lines.append(
        f"load average (1 min) during the run: start {la['start']:.2f}, mean {la['mean']:.2f}, max {la['max']:.2f}"
    )
    return "\n".join(lines)


def _main(args: argparse.Namespace) -> int:
    names = list(dict.fromkeys(args.only)) if args.only else list(RUNS)
    summary = run_all(names, args.out, jobs=args.jobs, quick=args.quick, seed_=args.seed)
    print(_table(summary), flush=True)
    print(f"timing: {args.out / 'timing.json'}", flush=True)
    return 1 if summary["failed"] else 0


def register(subparsers: Any) -> None:
    """Add ``distnav reproduce-all`` to the CLI."""
    p = subparsers.add_parser(
        "reproduce-all",
        help="every paper reproduction at full size, with their run times",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("--out", type=output_folder, required=True, help="run folder (one sub-folder per reproduction)")
    add_size_option(
        p,
        "--jobs",
        jobs_count,
        default=2,
        help="reproductions at once, and the workers of those that take --jobs (default 2)",
    )
    p.add_argument("--only", nargs="+", choices=list(RUNS), help="run only these")
    p.add_argument("--quick", action="store_true", help="the quick variants (a smoke test of the runner)")
    p.add_argument("--seed", type=seed, default=0, help="seed of every reproduction (default 0)")
    p.set_defaults(func=_main)

#!/usr/bin/env python3
"""Show that every ``distnav reproduce NAME --quick`` results.json is byte-identical between two trees.

    # 1. results of a tree (run with that tree's sources on the path), one folder per experiment:
    PYTHONPATH=TREE/src python scripts/compare_results.py --run OUT_DIR [--only consensus admm ...]
    # 2. compare two such folders (exit 0 if every results.json is byte-identical, 1 otherwise):
    python scripts/compare_results.py DIR_A DIR_B

``--run`` calls ``python -m distnav reproduce NAME --quick --out OUT_DIR/NAME --no-progress`` for every experiment
of the tree (``distnav.experiments.available()``) with the interpreter running this script (so ``PYTHONPATH``
picks the tree). The comparison reads
``DIR/NAME/results.json`` for every NAME in either folder; a file missing on one side is a difference. For a
differing pair it names the first JSON path whose value differs, to say where to look.

Wall-clock timings cannot repeat (``uwb`` records ``solver_seconds``): keys named in ``--volatile`` (default
``solver_seconds``) are dropped from both files, which must then agree byte for byte after re-serialization
(``json.dumps(indent=2)`` reproduces the writer's bytes, so only the dropped values may differ); such a pair is
reported as "identical except wall-clock ...".
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

EXPERIMENTS = ("consensus", "admm", "ckf", "uwb", "codebias", "ckf-ionosphere")  # if distnav is not importable


def _experiments() -> tuple[str, ...]:
    """The experiments of the tree on the path (new ones are compared too), else :data:`EXPERIMENTS`."""
    try:
        from distnav.experiments import available
    except ImportError:
        return EXPERIMENTS
    return tuple(available())


VOLATILE = ("solver_seconds", "cpu_s", "cpu_s_per_solve", "wall_s")  # timings: they cannot repeat


def _without(data: Any, keys: frozenset[str]) -> Any:
    if isinstance(data, dict):
        return {k: _without(v, keys) for k, v in data.items() if k not in keys}
    if isinstance(data, list):
        return [_without(v, keys) for v in data]
    return data


def run_all(out: Path, names: list[str]) -> int:
    """Run every quick reproduction into ``out/NAME``; returns the number that failed."""
    failed = 0
    for name in names:
        cmd = [sys.executable, "-m", "distnav", "reproduce", name, "--quick", "--out", str(out / name), "--no-progress"]
        print("$ " + " ".join(cmd), flush=True)
        rc = subprocess.run(cmd, env=os.environ.copy(), check=False).returncode
        if rc != 0:
            print(f"  {name}: exit code {rc}", flush=True)
            failed += 1
    return failed


def first_difference(a: Any, b: Any, where: str = "$") -> str | None:
    """The JSON path of the first value that differs between ``a`` and ``b`` (None if they are equal)."""
    if type(a) is not type(b):
        return f"{where}: {type(a).__name__} vs {type(b).__name__}"
    if isinstance(a, dict):
        for key in sorted(set(a) | set(b)):
            if key not in a or key not in b:
                return f"{where}.{key}: only in {'B' if key not in a else 'A'}"
            d = first_difference(a[key], b[key], f"{where}.{key}")
            if d:
                return d
        return None
    if isinstance(a, list):
        if len(a) != len(b):
            return f"{where}: length {len(a)} vs {len(b)}"
        for i, (x, y) in enumerate(zip(a, b, strict=True)):
            d = first_difference(x, y, f"{where}[{i}]")
            if d:
                return d
        return None
    return None if a == b else f"{where}: {a!r} vs {b!r}"


def compare(dir_a: Path, dir_b: Path, volatile: tuple[str, ...] = VOLATILE) -> int:
    """Print one line per experiment; returns the number of results.json that are not byte-identical."""
    names = sorted({p.parent.name for d in (dir_a, dir_b) for p in d.glob("*/results.json")})
    if not names:
        print(f"no */results.json under {dir_a} or {dir_b}")
        return 1
    bad = 0
    for name in names:
        fa, fb = dir_a / name / "results.json", dir_b / name / "results.json"
        if not fa.is_file() or not fb.is_file():
            print(f"DIFFERENT  {name}: results.json missing in {'A' if not fa.is_file() else 'B'}")
            bad += 1
            continue
        ba, bb = fa.read_bytes(), fb.read_bytes()
        if ba == bb:
            print(f"identical  {name} ({len(ba)} bytes)")
            continue
        try:
            ja, jb = json.loads(ba), json.loads(bb)
        except json.JSONDecodeError as exc:
            print(f"DIFFERENT  {name}: not JSON: {exc}")
            bad += 1
            continue
        keys = frozenset(volatile)
        ra, rb = (json.dumps(_without(j, keys), indent=2) + "\n" for j in (ja, jb))
        if ra == rb and json.dumps(ja, indent=2) + "\n" == ba.decode() and keys:
            print(f"identical  {name} ({len(ba)} bytes) except wall-clock {', '.join(sorted(keys))}")
            continue
        bad += 1
        print(f"DIFFERENT  {name}: {first_difference(ja, jb) or 'same JSON values, different bytes'}")
    print(f"{len(names) - bad} of {len(names)} results.json byte-identical")
    return bad


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("dirs", nargs="*", type=Path, help="DIR_A DIR_B to compare")
    parser.add_argument("--run", type=Path, metavar="OUT_DIR", help="run every quick reproduction into OUT_DIR")
    parser.add_argument("--only", nargs="+", metavar="NAME", help="with --run: only these experiments")
    parser.add_argument(
        "--volatile",
        nargs="*",
        default=list(VOLATILE),
        metavar="KEY",
        help="JSON keys holding wall-clock timings, ignored in the comparison (default: "
        f"{' '.join(VOLATILE)}; give none to compare every byte)",
    )
    args = parser.parse_args(argv)
    if args.run is not None:
        if args.dirs:
            parser.error("--run takes no DIR_A DIR_B")
        return 1 if run_all(args.run, list(args.only or _experiments())) else 0
    if len(args.dirs) != 2:
        parser.error("give DIR_A DIR_B (or --run OUT_DIR)")
    return 1 if compare(*args.dirs, volatile=tuple(args.volatile)) else 0


if __name__ == "__main__":
    sys.exit(main())

"""Run every ``benchmarks/bench_*.py``, write ``benchmarks/results/<area>.json`` and print one table each.

    python benchmarks/run.py [--quick] [--only consensus admm ...]
"""

from __future__ import annotations

import argparse
import importlib.util
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

from _common import print_table, write_json  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--only", nargs="+")
    args = ap.parse_args()
    for path in sorted(HERE.glob("bench_*.py")):
        area = path.stem.removeprefix("bench_")
        if args.only and area not in args.only:
            continue
        spec = importlib.util.spec_from_file_location(path.stem, path)
        assert spec and spec.loader
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        rows = mod.run(args.quick)
        print_table(area, rows)
        print(f"written {write_json(area, rows)}")


if __name__ == "__main__":
    main()

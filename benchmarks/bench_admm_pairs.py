"""ADMM per-pair iteration (Fig. 6 messages, the form that tolerates drops; issue 17 item 2) at the floor.

distnav's per-pair iteration without monitoring against :class:`bench_admm.BarePairKernel`, a bare numpy kernel of
the same iteration written without the exchange (pair index arrays, two gathers, two segment sums, the batched gain
product), n = 10³, 10⁴, 10⁵ (10³, 10⁴ with ``--quick``) on strip-numbered connected random geometric graphs (mean
degree 15), p = 10, m_i = 5, ρ = 3; timed interleaved, ratio min–median of the per-repeat ratios; the floor's
iterates are checked against distnav's. Goal ≤ 1.5×. Kept apart from ``bench_admm`` so it can be re-run alone.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import main_for  # noqa: E402
from bench_admm import pair_floor_rows  # noqa: E402


def run(quick: bool) -> list[dict[str, Any]]:
    return pair_floor_rows((1_000, 10_000) if quick else (1_000, 10_000, 100_000))


if __name__ == "__main__":
    main_for(__file__, run)

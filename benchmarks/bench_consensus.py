"""One consensus round through the exchange vs one scipy.sparse CSR product of the same size (the floor).

Random geometric graphs with mean degree ≈ 8, n = 10^3, 10^5, 10^6 nodes, payloads of 1 and 10 floats.
Goal (issue 2): distnav's round ≤ 2× the CSR product measured in the same run.
Also: a round with 10 % message drops (fault path), and the Monte Carlo probability measure (100,000 samples, n = 20).
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, main_for  # noqa: E402
from distnav.algorithms.consensus import consensus_probability, consensus_product, consensus_schedule  # noqa: E402
from distnav.exchange import FaultSchedule, make_exchange  # noqa: E402
from distnav.network import builders, consensus_weights  # noqa: E402


def run(quick: bool) -> list[dict]:
    rows: list[dict] = []
    sizes = [1_000, 100_000] if quick else [1_000, 100_000, 1_000_000]
    for n in sizes:
        t0 = time.perf_counter()
        g = builders.random_geometric(n, np.sqrt(8 / (np.pi * n)), rng=np.random.default_rng(0))
        build_s = time.perf_counter() - t0
        w = consensus_weights(g, "P3")
        csr = w.to_sparse()
        ex = make_exchange(g)
        mixer = ex.mixer(w)
        repeat = 20 if n <= 100_000 else 5
        for payload in (1, 10):
            x = np.random.default_rng(1).normal(size=(n, payload) if payload > 1 else n)
            ref = best_time(lambda x=x, csr=csr: csr @ x, repeat=repeat)
            ours = best_time(lambda x=x, mixer=mixer: mixer.apply(x), repeat=repeat)
            assert np.allclose(mixer.apply(x), csr @ x)
            rows.append({
                "name": "consensus round", "n_nodes": n, "mean_degree": round(float(g.degrees.mean()), 2),
                "payload_floats": payload, "distnav_ms": ours * 1e3, "csr_product_ms": ref * 1e3,
                "ratio": ours / ref, "goal": "≤ 2", "meets_goal": bool(ours / ref <= 2.0),
                "graph_build_s": round(build_s, 2),
            })
        if n <= 100_000:
            exf = make_exchange(g, faults=FaultSchedule(drop_probability=0.1, seed=1))
            mf = exf.mixer(w)
            x = np.random.default_rng(1).normal(size=(n, 10))
            ours = best_time(lambda x=x, mf=mf: mf.apply(x), repeat=repeat)
            ref = best_time(lambda x=x, csr=csr: csr @ x, repeat=repeat)
            rows.append({"name": "round with 10% drops", "n_nodes": n, "payload_floats": 10,
                         "distnav_ms": ours * 1e3, "csr_product_ms": ref * 1e3, "ratio": ours / ref,
                         "goal": "(no goal)"})
    g20 = builders.connected_random_geometric(20, mean_degree=4.9, rng=np.random.default_rng(2))
    L = consensus_product(consensus_schedule(g20, "P3"), 10)
    q = np.linspace(0, 1, 41)
    t = best_time(lambda: consensus_probability(L, q, samples=100_000, rng=np.random.default_rng(3)), repeat=3)
    rows.append({"name": "probability measure eq. (40)", "n_nodes": 20, "samples": 100_000,
                 "distnav_ms": t * 1e3, "goal": "well under 1 s", "meets_goal": bool(t < 1.0)})
    return rows


if __name__ == "__main__":
    main_for(__file__, run)

"""Consensus rounds through the exchange vs bare scipy kernels of the same work, measured in the same run.

Random geometric graphs with mean degree ≈ 8 (nodes numbered at random, as the builder draws them),
n = 10³, 10⁴, 10⁵, 10⁶ (10⁶ only without ``--quick``), payloads of 1 and 10 floats. Timings are interleaved
(:func:`paired_times`) and quoted as the min–median of the per-repeat ratios.

* **fault-free round** (issue 17 item 0): ``Mixer.apply`` on the exchange's local arrays (the exchange renumbers
  the nodes by reverse Cuthill–McKee at set-up) against the floor: one scipy CSR product ``W x`` with ``W``
  renumbered by RCM here (``W[p][:, p]``, scipy's own ordering routine). Goal ≤ 1.2×. The same product on the
  builder's random numbering is reported for reference.
* **round with 10 % drops** (item 1) against a bare drop round: draw a numpy random mask over the off-diagonal
  CSR entries, zero them, add their weight to the diagonal entries, one CSR product. Goal ≤ 1.5×.
* **round with 10 % drops against a fault-free round** (issue 27), 1 float per node: the drop round's ``Mixer.apply``
  against the fault-free mixer's on the same graph and start values, each in a loop ``x = mixer.apply(x)`` (as a
  consensus run calls it), in CPU time. Goal ≤ 1.5×. ``fault round`` in the
  row's name says which path ran: ``compiled`` (the optional kernel ``distnav._dropround``, built by pip from
  setup.py) or ``numpy`` (not built here, or ``DISTNAV_NO_KERNEL`` set). The drop rows against the bare drop round
  name it too. With the kernel, the row also splits the drop round's time: ``kernel_call_ms`` (the C round through
  one ctypes call, the struct of the last round) and ``python_ms`` (the rest of ``Mixer.apply``).
* set-up (exchange + mixer, including the RCM) is reported separately, as is the graph build.
* **peak memory** (item "peak memory, consensus at 10⁶ nodes"): ``mem_consensus.py`` in a fresh process per mode,
  distnav (builder graph, weights, exchange, mixer, 5 rounds) against the bare arrays of the same run written
  without distnav (the k-d tree's pairs, one RCM-renumbered CSR matrix, 5 products); the peak resident memory
  (``VmHWM``) of each process, 10⁶ nodes (10⁵ with ``--quick``), fault-free and with 10 % drops (against the bare
  drop round's arrays). Goal ≤ 1.2×.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from functools import partial
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import reverse_cuthill_mckee

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _common import best_time, main_for, paired_times, ratio_stats  # noqa: E402
from distnav._dropround import DropRound  # noqa: E402
from distnav.algorithms.consensus.averaging import consensus_probability, consensus_product, consensus_schedule  # noqa: E402
from distnav.exchange import FaultSchedule, make_exchange  # noqa: E402
from distnav.exchange.mixer import Mixer  # noqa: E402
from distnav.network import builders, consensus_weights  # noqa: E402

DROP = 0.1


class BareDropRound:
    """The floor of a drop round, written without distnav: mask the CSR data, move lost weight to the diagonal,
    one product. ``W`` must store every diagonal entry."""

    def __init__(self, W: sp.csr_matrix, p: float, seed: int) -> None:
        self.W = W.copy()
        self.base = W.data.copy()
        rows = np.repeat(np.arange(W.shape[0]), np.diff(W.indptr))
        diag = rows == W.indices
        self.diag_pos = np.flatnonzero(diag)
        assert self.diag_pos.size == W.shape[0], "every self-weight must be stored (P3 weights: all > 0)"
        self.off_pos = np.flatnonzero(~diag)
        self.off_rows = rows[~diag]
        self.p = p
        self.rng = np.random.default_rng(seed)

    def __call__(self, x: np.ndarray) -> Any:
        drop = self.rng.random(self.off_pos.size) < self.p
        data = self.base.copy()
        lost_pos = self.off_pos[drop]
        data[lost_pos] = 0.0
        data[self.diag_pos] += np.bincount(self.off_rows[drop], weights=self.base[lost_pos], minlength=self.W.shape[0])
        self.W.data = data
        return self.W @ x


def _fault_path(mixer: Mixer) -> str:
    """Which fault round a mixer ran: the compiled kernel or the numpy path."""
    return "compiled" if isinstance(mixer._kernel, DropRound) else "numpy"


def drop_vs_fault_free(lossy: Mixer, clean: Mixer, x_loc: np.ndarray, *, repeat: int, number: int) -> dict[str, Any]:
    """A round with 10 % drops against a fault-free round of the same graph, 1 float per node, each timed as a
    consensus loop runs it, ``x = mixer.apply(x)`` from ``x_loc`` (the drop round's output buffers are then reused):
    interleaved batches timed in CPU time (``time.process_time``, as ``bench_comm.py``: the machine is shared, and
    wall time counts the other processes' turns), ``2·repeat + 1`` pairs of ``5·number`` rounds each (batches of
    ≥ 5 ms: the CPU clock's resolution)."""
    lossy.apply(x_loc)  # the first fault round prepares the kernel: its path is then known
    clean.apply(x_loc)  # and a first fault-free round outside the clock too (else the first pair's floor is cold)
    t: dict[str, list[float]] = {"ours": [], "floor": []}
    for _ in range(2 * repeat + 1):
        for key, fn in (("floor", clean.apply), ("ours", lossy.apply)):
            x = x_loc
            t0 = time.process_time()
            for _ in range(5 * number):
                x = fn(x)
            t[key].append((time.process_time() - t0) / (5 * number))
    name = f"consensus round, 10% drops vs fault-free round, CPU time ({_fault_path(lossy)} fault round)"
    floor = "fault-free consensus round (Mixer.apply, same graph and values)"
    row = _drop_row(name, int(x_loc.shape[0]), 1, {k: np.asarray(v) for k, v in t.items()}, floor)
    row["timed"] = "loop x = mixer.apply(x)"
    kernel = lossy._kernel
    if isinstance(kernel, DropRound):  # where the round's time goes: the C round through ctypes, and the rest
        row["kernel_call_ms"] = _kernel_call_ms(kernel, 5 * number, 2 * repeat + 1)
        row["python_ms"] = row["distnav_ms"] - row["kernel_call_ms"]
    return row


def _kernel_call_ms(kernel: DropRound, number: int, batches: int) -> float:
    """The compiled round alone, called through ctypes with the argument struct of the last round (median CPU
    time of ``batches`` batches of ``number`` calls): what ``Mixer.apply`` adds is the rest. The calls add to the
    exchange's lost counter: it is restored after."""
    lost = kernel._lost
    saved = None if lost is None else lost.copy()
    times = []
    for _ in range(batches):
        t0 = time.process_time()
        for _ in range(number):
            kernel._call(kernel._byref)
        times.append((time.process_time() - t0) / number)
    if lost is not None and saved is not None:
        lost[:] = saved
    return float(np.median(times)) * 1e3


def _drop_row(name: str, n: int, payload: int, t: dict[str, np.ndarray], floor: str) -> dict[str, Any]:
    """A drop round's row: median times, the min–median of the per-repeat ratios, goal ≤ 1.5."""
    st = ratio_stats(t["ours"], t["floor"])
    return {
        "name": name,
        "n_nodes": n,
        "payload_floats": payload,
        "distnav_ms": float(np.median(t["ours"])) * 1e3,
        "floor_ms": float(np.median(t["floor"])) * 1e3,
        "floor": floor,
        **st,
        "goal": "≤ 1.5",
        "meets_goal": bool(st["ratio_median"] <= 1.5),
    }


def memory_rows(n: int, payload: int = 1, rounds: int = 5) -> list[dict[str, Any]]:
    """Peak resident memory of a consensus run, distnav against the bare arrays (one fresh process each), fault-free
    and with 10 % drops (the bare drop round's arrays: the masked CSR data and the diagonal and off-diagonal
    positions)."""
    script = Path(__file__).resolve().parent / "mem_consensus.py"
    rows: list[dict[str, Any]] = []
    for drop in (0.0, DROP):
        peak: dict[str, dict[str, Any]] = {}
        for mode in ("bare", "distnav"):
            proc = subprocess.run(
                [sys.executable, str(script), mode, str(n), str(payload), str(rounds), str(drop)],
                capture_output=True,
                text=True,
                timeout=1800,
                check=True,
            )
            peak[mode] = json.loads(proc.stdout.strip().splitlines()[-1])
        ours, bare = float(peak["distnav"]["end_mb"]), float(peak["bare"]["end_mb"])
        name = "peak memory, consensus (process peak resident memory)"
        rows.append(
            {
                "name": name if not drop else name.replace("consensus", f"consensus with {drop:.0%} drops"),
                "n_nodes": n,
                "payload_floats": payload,
                "drop": drop,
                "distnav_mb": ours,
                "bare_mb": bare,
                "floor": "bare numpy/scipy arrays of the same run",
                "ratio": ours / bare,
                "goal": "≤ 1.2",
                "meets_goal": bool(ours / bare <= 1.2),
                "distnav_stages_mb": {k: v for k, v in peak["distnav"].items() if k.endswith("_mb")},
                "bare_stages_mb": {k: v for k, v in peak["bare"].items() if k.endswith("_mb")},
            }
        )
    return rows


def run(quick: bool) -> list[dict[str, Any]]:
    rows: list[dict[str, Any]] = memory_rows(100_000 if quick else 1_000_000)
    sizes = [1_000, 10_000, 100_000] if quick else [1_000, 10_000, 100_000, 1_000_000]
    for n in sizes:
        t0 = time.perf_counter()
        g = builders.random_geometric(n, np.sqrt(8 / (np.pi * n)), rng=np.random.default_rng(0))
        build_s = time.perf_counter() - t0
        w = consensus_weights(g, "P3")
        csr = w.to_sparse().tocsr()
        t0 = time.perf_counter()
        ex = make_exchange(g, order="auto")  # the locality order inside; ex.local / gather_nodes at the boundary
        mixer = ex.mixer(w)
        setup_s = time.perf_counter() - t0
        perm = reverse_cuthill_mckee(csr, symmetric_mode=True)
        csr_rcm = csr[perm][:, perm].tocsr()
        repeat = 7 if n <= 100_000 else 3
        number = max(1, 200_000 // n)
        for payload in (1, 10):
            x = np.random.default_rng(1).normal(size=(n, payload) if payload > 1 else n)
            x_rcm = np.ascontiguousarray(x[perm])
            x_loc = ex.local(x)
            assert np.allclose(ex.gather_nodes(mixer.apply(x_loc)), csr @ x, rtol=1e-13, atol=1e-15)
            t = paired_times(
                {
                    "ours": partial(mixer.apply, x_loc),
                    "floor": partial(csr_rcm.dot, x_rcm),
                    "random": partial(csr.dot, x),
                },
                repeat=repeat,
                number=number,
            )
            st = ratio_stats(t["ours"], t["floor"])
            rows.append(
                {
                    "name": "consensus round, fault-free",
                    "n_nodes": n,
                    "payload_floats": payload,
                    "distnav_ms": float(np.median(t["ours"])) * 1e3,
                    "floor_ms": float(np.median(t["floor"])) * 1e3,
                    "floor": "scipy CSR product, RCM-renumbered",
                    **st,
                    "goal": "≤ 1.2",
                    "meets_goal": bool(st["ratio_median"] <= 1.2),
                    "random_order_product_ms": float(np.median(t["random"])) * 1e3,
                    "setup_s": setup_s,
                    "graph_build_s": build_s,
                    "mean_degree": round(float(g.degrees.mean()), 2),
                }
            )
        if n <= 100_000 or not quick:
            t0 = time.perf_counter()
            exf = make_exchange(g, faults=FaultSchedule(drop_probability=DROP, seed=1), order="auto")
            mf = exf.mixer(w)
            setup_f = time.perf_counter() - t0
            bare = BareDropRound(csr_rcm, DROP, 2)
            x = np.random.default_rng(1).normal(size=(n, 10))
            x_loc = exf.local(x)
            x_rcm = np.ascontiguousarray(x[perm])
            t = paired_times(
                {
                    "ours": partial(mf.apply, x_loc),
                    "floor": partial(bare, x_rcm),
                    "fault_free": partial(mixer.apply, x_loc),
                },
                repeat=repeat,
                number=number,
            )
            floor = "bare drop round (masked CSR data, lost weight to the diagonal, one product)"
            row = _drop_row(f"consensus round, 10% drops ({_fault_path(mf)} fault round)", n, 10, t, floor)
            row["vs_fault_free_round"] = float(np.median(t["ours"] / t["fault_free"]))
            rows.append({**row, "setup_s": setup_f})
            rows.append(drop_vs_fault_free(mf, mixer, exf.local(x[:, 0]), repeat=repeat, number=number))
    g20 = builders.connected_random_geometric(20, mean_degree=4.9, rng=np.random.default_rng(2))
    L = consensus_product(consensus_schedule(g20, "P3"), 10)
    q = np.linspace(0, 1, 41)
    t1 = best_time(lambda: consensus_probability(L, q, samples=100_000, rng=np.random.default_rng(3)), repeat=3)
    rows.append(
        {
            "name": "probability measure eq. (40)",
            "n_nodes": 20,
            "samples": 100_000,
            "distnav_ms": t1 * 1e3,
            "goal": "well under 1 s",
            "meets_goal": bool(t1 < 1.0),
        }
    )
    return rows


if __name__ == "__main__":
    main_for(__file__, run)

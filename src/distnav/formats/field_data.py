"""A field node's own data file for the algorithms beyond consensus: ADMM's observation block, the CKF's normals.

One ``.npz`` file per node (numpy's zip of ``.npy`` arrays: a documented, language-neutral layout, read without
pickle), written by ``distnav field init --simulate`` (or by :func:`write_node_arrays` from a user's own model) and
read by ``distnav node`` on that node's host. A file holds **only that node's data** plus what every node knows alike
(the parameter names, the common dynamic model): a node never sees another node's observations.

========  =====================================================================================================
kind      arrays
========  =====================================================================================================
``admm``  ``A`` (m × p), ``y`` (m), ``R`` (m × m): the node's block of the linear problem (paper 000 eq. (1)),
          zero-padded to the network's largest row count ``m`` exactly as the in-process problem stores it (so the
          node's products are the in-process ones bit for bit), ``rows`` (its true row count)
``ckf``   ``N`` (T × p × p), ``r`` (T × p): the node's normals per epoch (paper 003 eq. (24)); the common dynamic
          model ``phi`` (p × p, or T × p × p) and its noise factor ``H/k`` (p × q_k), ``S/k`` (q_k × q_k) per stored
          epoch ``k`` (one when constant)
``uwb``   ``samples`` (k × 4): the anchor's own range samples ``[sample index, a, b, range_m]`` (every sample of a
          link it is an end of); the anchor table every node knows alike (as a survey would give it): ``ids``,
          ``positions_m`` (n × dim, known coordinates), ``free`` (n × dim), ``initial_m`` (n × dim), ``n_samples``
          and, for simulations, ``truth_m``
========  =====================================================================================================

Every file also holds ``kind``, ``node`` (its node id) and ``n_nodes``; :func:`read_node_arrays` checks them against
the description (a file copied to the wrong host is refused, naming both ids).
"""

from __future__ import annotations

import io
import os
import zipfile
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from distnav.errors import DataFileError

if TYPE_CHECKING:
    from distnav.algorithms.kalman.dynamics import DynamicModel
    from distnav.algorithms.kalman.measurements import MeasurementSeries
    from distnav.algorithms.lsq.blue import LinearProblem
    from distnav.algorithms.ranging.data import RangingData

__all__ = [
    "KINDS",
    "admm_node_arrays",
    "admm_node_problem",
    "ckf_node_arrays",
    "ckf_node_model",
    "uwb_node_arrays",
    "uwb_samples_problem",
    "read_node_arrays",
    "write_node_arrays",
]

KINDS = {
    "admm": ("A", "y", "R", "rows"),
    "ckf": ("N", "r", "phi", "n_noise"),
    "uwb": ("samples", "ids", "positions_m", "free", "initial_m", "n_samples"),
}


def write_node_arrays(path: Path, kind: str, node_id: int, n_nodes: int, arrays: dict[str, np.ndarray]) -> None:
    """Write node ``node_id``'s file (atomically: a temporary file in the same folder, then a rename)."""
    if kind not in KINDS:
        raise DataFileError(f"{path}: unknown node data kind {kind!r} (one of {sorted(KINDS)})")
    missing = [k for k in KINDS[kind] if k not in arrays]
    if missing:
        raise DataFileError(f"{path}: node {node_id}: {kind} data needs arrays {missing}")
    buf = io.BytesIO()
    header = {"kind": np.array(kind), "node": np.array(node_id, np.int64), "n_nodes": np.array(n_nodes, np.int64)}
    content: dict[str, Any] = {**header, **{k: np.asarray(v) for k, v in arrays.items()}}
    np.savez(buf, **content)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(buf.getvalue())
    os.replace(tmp, path)


def read_node_arrays(path: Path, kind: str, node_id: int, n_nodes: int) -> dict[str, np.ndarray]:
    """Node ``node_id``'s arrays; :class:`DataFileError` names the file and what is wrong (not a node data file,
    another kind, another node's or network's file, a missing array)."""
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except FileNotFoundError:
        raise DataFileError(f"{path}: node {node_id}: its data file does not exist") from None
    except (OSError, ValueError, zipfile.BadZipFile, EOFError) as exc:
        raise DataFileError(f"{path}: node {node_id}: not a node data file (.npz without pickles): {exc}") from None
    for key in ("kind", "node", "n_nodes"):
        if key not in arrays or arrays[key].ndim != 0:
            raise DataFileError(f"{path}: node {node_id}: not a distnav node data file (no '{key}')")
    if str(arrays["kind"]) != kind:
        raise DataFileError(f"{path}: node {node_id}: holds {str(arrays['kind'])!r} data, the algorithm needs {kind!r}")
    if int(arrays["node"]) != node_id or int(arrays["n_nodes"]) != n_nodes:
        raise DataFileError(
            f"{path}: this is the file of node {int(arrays['node'])} of a {int(arrays['n_nodes'])}-node network, "
            f"not of node {node_id} of this {n_nodes}-node description"
        )
    missing = [k for k in KINDS[kind] if k not in arrays]
    if missing:
        raise DataFileError(f"{path}: node {node_id}: {kind} data without arrays {missing}")
    bad = [k for k, v in arrays.items() if v.dtype.kind == "f" and not np.all(np.isfinite(v)) and k != "truth_m"]
    if bad:
        raise DataFileError(f"{path}: node {node_id}: arrays {bad} hold non-finite values")
    return arrays


# ----------------------------------------------------------------------------------------------- ADMM
def admm_node_arrays(problem: LinearProblem, node_id: int) -> dict[str, np.ndarray]:
    """Node ``node_id``'s block of ``problem`` (padded as stored, see the module docstring)."""
    i = int(node_id)
    out = {"A": problem.A[i], "y": problem.y[i], "R": problem.R[i], "rows": np.array(problem.rows[i], np.int64)}
    if problem.parameter_names is not None:
        out["parameter_names"] = np.array(problem.parameter_names)
    return out


def admm_node_problem(arrays: dict[str, np.ndarray], path: Path, node_id: int, n_nodes: int) -> LinearProblem:
    """A :class:`LinearProblem` of ``n_nodes`` nodes for node ``node_id``'s program: its own block, and in every
    other node's place a read-only view of the same block (no memory; the node code reads only its own rows,
    ``problem.subset(ex.nodes)``, so no other node's data is needed or invented)."""
    from distnav.algorithms.lsq.blue import LinearProblem

    A, y, R = (np.asarray(arrays[k], dtype=float) for k in ("A", "y", "R"))
    if A.ndim != 2 or y.shape != (A.shape[0],) or R.shape != (A.shape[0], A.shape[0]):
        raise DataFileError(f"{path}: node {node_id}: shapes A {A.shape}, y {y.shape}, R {R.shape} do not agree")
    rows = int(arrays["rows"])
    if not 0 <= rows <= A.shape[0]:
        raise DataFileError(f"{path}: node {node_id}: rows = {rows}, but A has {A.shape[0]} rows")
    own = LinearProblem.from_blocks([A], [y], [R])  # the same checks as any problem (R symmetric, PD, finite)
    names = arrays.get("parameter_names")
    n = int(n_nodes)
    return LinearProblem(
        A=np.broadcast_to(own.A, (n, *A.shape)),
        y=np.broadcast_to(own.y, (n, *y.shape)),
        R=np.broadcast_to(own.R, (n, *R.shape)),
        rows=np.full(n, rows, np.int64),
        parameter_names=None if names is None else tuple(str(s) for s in names.tolist()),
    )


# ----------------------------------------------------------------------------------------------- CKF
def ckf_node_arrays(dynamics: DynamicModel, series: MeasurementSeries, node_id: int) -> dict[str, np.ndarray]:
    """Node ``node_id``'s normals of every epoch and the common dynamic model (module docstring)."""
    T = series.n_epochs
    idx = np.array([node_id], np.int64)
    normals = [series.normals(t, idx) for t in range(T)]
    out: dict[str, np.ndarray] = {"N": np.stack([n[0][0] for n in normals]), "r": np.stack([n[1][0] for n in normals])}
    phis = [dynamics.transition_at(t) for t in range(1, T)] or [dynamics.transition_at(0)]
    const_phi = all(np.array_equal(f, phis[0]) for f in phis)
    out["phi"] = phis[0] if const_phi else np.stack([dynamics.transition_at(0), *phis])
    factors = [dynamics.noise_factor_at(t)[:2] for t in range(1, T)] or [dynamics.noise_factor_at(0)[:2]]
    const_noise = all(np.array_equal(h, factors[0][0]) and np.array_equal(s, factors[0][1]) for h, s in factors)
    stored = factors[:1] if const_noise else [dynamics.noise_factor_at(0)[:2], *factors]
    out["n_noise"] = np.array(len(stored) if not const_noise else 0, np.int64)  # 0: constant
    for k, (H, S) in enumerate(stored):
        out[f"H/{k}"], out[f"S/{k}"] = H, S
    return out


def ckf_node_model(
    arrays: dict[str, np.ndarray], path: Path, node_id: int, n_nodes: int
) -> tuple[DynamicModel, MeasurementSeries]:
    """The common dynamic model and a measurement series that answers for this node only (asking for another node's
    normals is an error: the node does not have them)."""
    from distnav.algorithms.kalman.dynamics import DynamicModel
    from distnav.algorithms.kalman.measurements import FunctionSeries
    from distnav.errors import ModelError

    N, r = np.asarray(arrays["N"], float), np.asarray(arrays["r"], float)
    if N.ndim != 3 or N.shape[1] != N.shape[2] or r.shape != N.shape[:2]:
        raise DataFileError(f"{path}: node {node_id}: normals of shapes N {N.shape}, r {r.shape} do not agree")
    T, p = N.shape[0], N.shape[1]
    count = int(arrays["n_noise"])
    keys = range(max(count, 1))
    try:
        H = [np.asarray(arrays[f"H/{k}"], float) for k in keys]
        S = [np.asarray(arrays[f"S/{k}"], float) for k in keys]
    except KeyError as exc:
        raise DataFileError(f"{path}: node {node_id}: the noise factor {exc.args[0]} is missing") from None
    try:
        dyn = DynamicModel(
            p,
            transition=arrays["phi"],
            noise_map=H[0] if count == 0 else H,
            noise_reduced_cov=S[0] if count == 0 else S,
        )
    except ModelError as exc:
        raise DataFileError(f"{path}: node {node_id}: the dynamic model: {exc}") from None
    me = int(node_id)

    def own_normals(t: int, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        if nodes.tolist() != [me]:
            raise ModelError(f"node {me} holds only its own normals, not those of nodes {nodes.tolist()}")
        return N[t][None], r[t][None]

    return dyn, FunctionSeries(n_nodes, T, p, own_normals)


# ----------------------------------------------------------------------------------------------- UWB
def uwb_node_arrays(problem: RangingData, node_id: int) -> dict[str, np.ndarray]:
    """Anchor ``node_id``'s own range samples and the common anchor table (module docstring)."""
    i = int(node_id)
    own = np.flatnonzero((problem.meas_a == i) | (problem.meas_b == i))
    samples = np.stack([own, problem.meas_a[own], problem.meas_b[own], problem.range_m[own]], axis=1).astype(float)
    initial = problem.initial_m if problem.initial_m is not None else problem.positions_m
    out = {
        "samples": samples,
        "ids": np.array(problem.ids),
        "dim": np.array(problem.dim, np.int64),
        "positions_m": problem.positions_m,
        "free": problem.free,
        "initial_m": initial,
        "n_samples": np.array(problem.n_meas, np.int64),
    }
    if problem.truth_m is not None:
        out["truth_m"] = problem.truth_m
    return out


def uwb_samples_problem(arrays: dict[str, np.ndarray], samples: np.ndarray, path: Path) -> RangingData:
    """The ranging problem from the anchor table of ``arrays`` and ``samples`` (rows ``[index, a, b, range_m]``,
    every index ``0..n_samples − 1`` at least once, in any order, duplicates equal); :class:`DataFileError` names a
    missing sample or two anchors that disagree on one."""
    from distnav.algorithms.ranging.data import RangingData

    m = int(arrays["n_samples"])
    idx = samples[:, 0].astype(np.int64)
    order = np.argsort(idx, kind="stable")
    s, k = samples[order], idx[order]
    first = np.r_[True, k[1:] != k[:-1]]
    dup = ~first
    if dup.any():
        prev = np.flatnonzero(dup) - 1
        differ = np.flatnonzero(~np.all(s[dup] == s[prev], axis=1))
        if differ.size:
            j = int(np.flatnonzero(dup)[differ[0]])
            raise DataFileError(f"{path}: the two ends of range sample {int(k[j])} disagree: {s[j]} vs {s[j - 1]}")
    s, k = s[first], k[first]
    if k.size != m or not np.array_equal(k, np.arange(m)):
        missing = sorted(set(range(m)) - set(k.tolist()))[:10]
        raise DataFileError(f"{path}: range samples {missing} reached no anchor (each must be in both ends' files)")
    truth = arrays.get("truth_m")
    return RangingData(
        ids=tuple(str(x) for x in arrays["ids"].tolist()),
        dim=int(arrays["dim"]) if "dim" in arrays else int(arrays["positions_m"].shape[1]),
        positions_m=np.asarray(arrays["positions_m"], float),
        free=np.asarray(arrays["free"], bool),
        meas_a=s[:, 1].astype(np.int64),
        meas_b=s[:, 2].astype(np.int64),
        range_m=s[:, 3].copy(),
        truth_m=None if truth is None else np.asarray(truth, float),
        initial_m=np.asarray(arrays["initial_m"], float),
    )

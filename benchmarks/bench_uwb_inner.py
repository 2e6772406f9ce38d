"""The inner solve of the distributed LM phase on 12 plant-like workflows (issue 27, seventh session).

    python benchmarks/bench_uwb_inner.py [--quick] [--study]

For each of the 12 workflows (plant-like 28-anchor halls ``[78, k]``, k = 0…5, known anchors in the middle and in a
corner; ``uwb solve``'s workflow ``solve_field`` with N-CLM) every inner solve of the LM phase (``refine.pcg``) is
recorded: its CG iterations, the bytes its products sent on the links and its reductions' bytes as spanning-tree
all-reductions (``wire.reduction_cost``), per workflow, per fit (``refine.refine`` calls) and per LM round — and what
the LM rounds' own methods sent (``refine._Refiner.start`` / ``evaluate`` / ``linearize``: the start's offset mean,
the first evaluation, every trial's step and its objective and largest move, the extrapolated trials, the common
offset's row; broadcast messages and bytes, reductions as spanning-tree bytes) — in the configurations of
:data:`CONFIGS`, in one run: the defaults at the seventh session's start (*before*: items 24–32 and 36 off), with
items 26–27 (*inner*: ``wire.HELD_DOTS``, ``wire.HELD_ACROSS_RUNS``), with items 24–27 (*loop*:
``field_fits.TIGHTEN_OPENS_LOOP``, ``LOOP_ENDS_LOOSE`` too), with items 24–32 (*rounds*: the rounds' own messages too),
the seventh session's end (*after*: ``field_fits.STAGE_FORCING`` too, item 36) and the defaults (*sit_out*:
``refine.SIT_OUT`` too, item 37 of the eighth session); every position, σ,
exclusion and status compared with the configuration before it.

``--study`` also rebuilds every inner system densely (numpy, from the linearization the solve used) and counts the
iterations that preconditioned CG needs to the same stop (``rᵀz ≤ rtol² · bᵀM⁻¹b``, float64) — as is; deflated by
the exact eigenvectors of the smallest eigenvalues of ``M⁻¹A`` (an oracle no anchor has: what a perfect coarse
space would save); and deflated by coarse spaces every anchor can build from its own row (the rigid motions of the
free anchors: per cluster of anchors, translations and the rotation about the cluster's centre; the rotation about
the known anchors' centre alone), each as full
deflation (DPCG: the coarse correction in every iteration, Saad et al. 2000 / Tang et al. 2009 "A-DEF2") and as a
deflated start only (the coarse solve once, then plain PCG). Printed as one table; JSON in
benchmarks/results/uwb_inner.json.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import numpy as np

import bench_uwb_economy as economy
from _common import print_table, write_json
from distnav.algorithms.ranging import refine, wire
from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb import field_fits
from distnav.models.uwb.field import FieldOptions, prepare, solve_field
from distnav.models.uwb.field import gather_cost as range_gather_cost
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall

WORKFLOWS = [(k, place) for k in range(6) for place in ("middle", "corner")]
QUICK = [(0, "middle"), (0, "corner")]
_CALLS: list[dict[str, Any]] = []
_STUDY = False


def _dense(system: Any, links: Any) -> tuple[np.ndarray, np.ndarray]:
    """The damped normal matrix of ``system`` over its free unknowns (numpy), and the free mask (flattened)."""
    nodes = np.asarray(links.ex.nodes)
    assert np.array_equal(nodes, np.arange(nodes.size)), "the study needs one in-process block"
    nl, P = system.free.shape
    n_u = nl * P + 1
    h = system.owner.size
    J = np.zeros((h, n_u))
    rows = np.arange(h)
    for p in range(P):
        J[rows, system.owner * P + p] += system.a[:, p]
        J[rows, links.other * P + p] += system.cn[:, p]
    J[:, -1] = system.e
    A = np.zeros((n_u, n_u))
    for p in range(P):
        np.add.at(A, system.owner * P + p, (system.w * system.a[:, p])[:, None] * J)
    A[-1] += 0.5 * (system.w * system.e) @ J
    A[np.arange(nl * P), np.arange(nl * P)] += system.damp.ravel()
    if system.prior:
        A[np.arange(nl) * P + P - 1, np.arange(nl) * P + P - 1] += system.prior
    A[-1, -1] += system.damp_c
    keep = np.r_[system.free.ravel(), system.common]
    return A[np.ix_(keep, keep)], keep


def _pcg_its(A: np.ndarray, Minv: np.ndarray, b: np.ndarray, rtol: float, Z: np.ndarray | None, full: bool) -> int:
    """Iterations of PCG (float64) to ``rᵀz ≤ rtol² bᵀM⁻¹b``; ``Z``: deflated start (and with ``full`` the coarse
    correction every iteration, A-DEF2)."""
    ref = float(b @ Minv @ b)
    x = np.zeros_like(b)
    coarse = None
    if Z is not None:
        AZ = A @ Z
        E = Z.T @ AZ
        coarse = (AZ, np.linalg.inv(E))
        x = Z @ (coarse[1] @ (Z.T @ b))
    r = b - A @ x
    z = Minv @ r
    p = z - (Z @ (coarse[1] @ (coarse[0].T @ z)) if coarse is not None and full else 0.0)
    rz = float(r @ z)
    its = 0
    while rz > rtol**2 * ref and its < 4 * b.size:
        its += 1
        q = A @ p
        alpha = rz / float(p @ q)
        x += alpha * p
        r -= alpha * q
        z = Minv @ r
        rz_new = float(r @ z)
        if rz_new <= rtol**2 * ref:
            break
        p = z + (rz_new / rz) * p
        if coarse is not None and full:
            p -= Z @ (coarse[1] @ (coarse[0].T @ z))
        rz = rz_new
    return its


def _rigid(system: Any, x_m: np.ndarray, clusters: np.ndarray) -> np.ndarray:
    """Per cluster of anchors the horizontal rigid motions of its free anchors (x, y translations and the rotation
    about the cluster's centre), as columns over the free unknowns (the common offset: zero)."""
    nl, P = system.free.shape
    cols = []
    for c in np.unique(clusters):
        at = (clusters == c) & system.free[:, 0]
        if not at.any():
            continue
        centre = x_m[at, :2].mean(axis=0)
        for vec in (np.eye(2)[0], np.eye(2)[1], None):
            z = np.zeros((nl, P))
            if vec is None:
                z[at, 0], z[at, 1] = -(x_m[at, 1] - centre[1]), x_m[at, 0] - centre[0]
            else:
                z[at, :2] = vec
            cols.append(np.r_[z.ravel(), 0.0])
    return np.array(cols).T


def _clusters(x_m: np.ndarray, k: int) -> np.ndarray:
    """``k`` clusters of the anchors by their x coordinate's angle about the centroid (k = 1: all)."""
    if k == 1:
        return np.zeros(x_m.shape[0], int)
    d = x_m[:, :2] - x_m[:, :2].mean(axis=0)
    ang = np.arctan2(d[:, 1], d[:, 0])
    return np.minimum(((ang + np.pi) / (2 * np.pi) * k).astype(int), k - 1)


def _study(
    system: Any, b: np.ndarray, bc: np.ndarray, pre_inv: np.ndarray, pre_c: float, links: Any, rtol: float
) -> dict[str, Any]:
    A, keep = _dense(system, links)
    nl, P = system.free.shape
    Mi = np.zeros((nl * P + 1, nl * P + 1))
    for i in range(nl):
        Mi[i * P : (i + 1) * P, i * P : (i + 1) * P] = pre_inv[i]
    Mi[-1, -1] = 1.0 / pre_c
    Mi = Mi[np.ix_(keep, keep)]
    rhs = np.r_[b[:, :, 0].ravel(), bc[0]][keep]
    out: dict[str, Any] = {"plain": _pcg_its(A, Mi, rhs, rtol, None, False)}
    L = np.linalg.cholesky(np.linalg.inv(Mi))  # M = L Lᵀ: M⁻¹A ~ L⁻¹ A L⁻ᵀ
    Li = np.linalg.inv(L)
    lam, V = np.linalg.eigh(Li @ A @ Li.T)
    W = Li.T @ V  # generalized eigenvectors A w = λ M w
    out["lam_min"], out["lam_max"] = float(lam[0]), float(lam[-1])
    out["lam"] = lam[:6].tolist()
    for k in (1, 2, 3, 4, 6):
        out[f"oracle{k}_full"] = _pcg_its(A, Mi, rhs, rtol, W[:, :k], True)
        out[f"oracle{k}_start"] = _pcg_its(A, Mi, rhs, rtol, W[:, :k], False)
    x_m = np.asarray(links.wire._problem.positions_m)  # noqa: SLF001 (the study only: the anchors' rows)
    x_m = _POS[0] if _POS else x_m
    for k in (1, 2, 4):
        Z = _rigid(system, x_m, _clusters(x_m, k))[keep]
        out[f"rigid{k}_full"] = _pcg_its(A, Mi, rhs, rtol, Z, True)
        out[f"rigid{k}_start"] = _pcg_its(A, Mi, rhs, rtol, Z, False)
        out[f"rigid{k}_m"] = Z.shape[1]
    known = ~system.free[:, 0]
    centre = x_m[known, :2].mean(axis=0) if known.any() else x_m[:, :2].mean(axis=0)
    z = np.zeros((nl, P))
    z[:, 0], z[:, 1] = -(x_m[:, 1] - centre[1]), x_m[:, 0] - centre[0]
    Z = (np.r_[z.ravel(), 0.0][:, None])[keep]
    out["rotknown_full"] = _pcg_its(A, Mi, rhs, rtol, Z, True)
    out["rotknown_start"] = _pcg_its(A, Mi, rhs, rtol, Z, False)
    return out


_POS: list[np.ndarray] = []


def _recording() -> None:
    pcg, linearize = refine.pcg, refine._Refiner.linearize

    def lin(self: Any, x: np.ndarray, nb: np.ndarray, r: np.ndarray) -> Any:
        _POS[:] = [x[:, : self.dim].copy()]
        out = linearize(self, x, nb, r)
        _CALLS.append({"round": True})
        return out

    def recorded(
        system: Any,
        b: np.ndarray,
        bc: np.ndarray,
        pre_inv: np.ndarray,
        pre_c: float,
        links: Any,
        max_its: int,
        **kw: Any,
    ) -> Any:
        c0, r0 = links.ex.comm_totals().bytes, links.reduced_bytes
        out = pcg(system, b, bc, pre_inv, pre_c, links, max_its, **kw)
        per = 2 * ((links.counted().tree_nodes or links.n) - 1)  # the tree of the anchors that take part (item 37)
        rec: dict[str, Any] = {
            "its": out[2],
            "product_bytes": links.ex.comm_totals().bytes - c0,
            "reduction_bytes": (links.reduced_bytes - r0) * per,
        }
        if _STUDY:
            rec.update(_study(system, b, bc, pre_inv, pre_c, links, kw.get("rtol", refine.CG_RTOL)))
        _CALLS.append(rec)
        return out

    refine.pcg = recorded  # type: ignore[assignment]
    refine._Refiner.linearize = lin  # type: ignore[method-assign]
    fit = refine.refine

    def counted_fit(*args: Any, **kw: Any) -> Any:
        _CALLS.append({"fit": True})
        return fit(*args, **kw)

    refine.refine = counted_fit  # type: ignore[assignment]
    _counting_rounds()


#: the LM rounds' own messages by kind (seventh session, items 28–32), per workflow: broadcast bytes and messages,
#: reduction bytes (spanning-tree, as ``wire.reduction_cost``)
_KINDS: dict[str, list[int]] = {}
_IN_EXTRAPOLATION = [False]


def _kind_of(name: str, args: tuple[Any, ...], kw: dict[str, Any]) -> str:
    if name != "evaluate":
        return {"start": "start (offset mean)", "linearize": "offset row"}[name]
    base = args[3] if len(args) > 3 else kw.get("base")
    return "first evaluation" if base is None else ("extrapolation" if _IN_EXTRAPOLATION[0] else "trial")


def _counting_rounds() -> None:
    """Wrap the LM phase's round methods (``refine._Refiner``): what each sends, by kind (:data:`_KINDS`)."""
    for name in ("start", "evaluate", "linearize"):
        orig = getattr(refine._Refiner, name)

        def counted(self: Any, *args: Any, _orig: Any = orig, _name: str = name, **kw: Any) -> Any:
            c0 = self.links.ex.comm_totals()
            m0, b0, r0, d0 = c0.messages, c0.bytes, self.links.reduced_bytes, self.links.decided[2]
            out = _orig(self, *args, **kw)
            c1 = self.links.ex.comm_totals()
            k = _KINDS.setdefault(_kind_of(_name, args, kw), [0, 0, 0, 0])
            k[0] += 1
            k[1] += c1.messages - m0
            k[2] += c1.bytes - b0
            edges = (self.links.counted().tree_nodes or self.links.n) - 1  # item 37: the known anchors sit out
            k[3] += ((self.links.reduced_bytes - r0) * 2 + self.links.decided[2] - d0) * edges
            return out

        setattr(refine._Refiner, name, counted)
    extrapolate = refine._Refiner.extrapolate

    def flagged(self: Any, *args: Any, **kw: Any) -> Any:
        _IN_EXTRAPOLATION[0] = True
        try:
            return extrapolate(self, *args, **kw)
        finally:
            _IN_EXTRAPOLATION[0] = False

    refine._Refiner.extrapolate = flagged  # type: ignore[method-assign]


def _solve(k: int, place: str) -> tuple[Any, Any, dict[str, Any]]:
    """One workflow's ``solve_field`` (defaults as configured) and its inner solves' counts."""
    h = simulate_hall(np.random.default_rng([78, k]), HallConfig().with_(known=place, **PLANT_LIKE))
    sub, geo = prepare(hall_problem(h)[0])
    _CALLS.clear()
    _KINDS.clear()
    t0 = time.process_time()
    sol = solve_field(sub, FieldOptions(solver="N-CLM"), geometry=geo)
    cpu = time.process_time() - t0
    per_anchor = economy._per_anchor_bytes(sub, sol)
    solves = [c for c in _CALLS if "its" in c]
    rounds = sum(1 for c in _CALLS if "round" in c)
    fits = sum(1 for c in _CALLS if "fit" in c)
    its = sum(c["its"] for c in solves)
    d = (sol.positions_m - sub.truth_m)[sub.estimated]
    row: dict[str, Any] = {
        "bytes": sol.bytes,
        "x_gather": sol.bytes / range_gather_cost(sub)["bytes"],
        "median_anchor_bytes": float(np.median(per_anchor)),
        "fits": fits,
        "lm_rounds": rounds,
        "cg_its": its,
        "cg_its_per_fit": its / max(fits, 1),
        "cg_its_per_round": its / max(rounds, 1),
        "product_bytes": sum(c["product_bytes"] for c in solves),
        "reduction_bytes": sum(c["reduction_bytes"] for c in solves),
        "rmse_m": float(np.sqrt(np.mean(np.sum(d**2, axis=1)))),
        "status": sol.status,
        "cpu_s": cpu,
    }
    for kind, (calls, msgs, bcast, red) in sorted(_KINDS.items()):
        row[f"{kind}: calls, broadcast msgs / B, reduction B"] = f"{calls}, {msgs} / {bcast}, {red}"
    row["rounds_own_bytes"] = sum(k[2] + k[3] for k in _KINDS.values())
    row["rounds_own_share"] = row["rounds_own_bytes"] / sol.bytes
    row["cg_bytes_per_it"] = (row["product_bytes"] + row["reduction_bytes"]) / max(its, 1)
    row["cg_share"] = (row["product_bytes"] + row["reduction_bytes"]) / sol.bytes
    if _STUDY:
        for key in solves[0]:
            if key in ("its", "product_bytes", "reduction_bytes", "lam") or key.endswith("_m"):
                continue
            vals = [c[key] for c in solves]
            row[f"dense_{key}"] = float(np.min(vals)) if key.startswith("lam") else float(np.sum(vals))
        row["coarse_columns"] = {k2: solves[0][k2] for k2 in solves[0] if k2.endswith("_m")}
    return sub, sol, row


#: the configurations compared, in one run (module, switch, value), each against the one before it: the defaults at
#: the seventh session's start (*before*: items 24–32 and 36 off), with items 26–27 (*inner*: CG's dot products and
#: the products' exponents held), with items 24–27 (*loop*: the exclusion loop opened by the last tightening fit and
#: ended on its decided 1 cm re-fit too), with items 24–32 (*rounds*: the LM rounds' own messages too) and the
#: defaults (*after*: the forcing term in the loop's re-fits too, item 36)
_LOOP_OFF = [(field_fits, "TIGHTEN_OPENS_LOOP", False), (field_fits, "LOOP_ENDS_LOOSE", False)]
_ROUNDS_OFF = [
    (wire, "STEP_HELD", False),
    (refine, "FIRST_MOVE_KNOWN", False),
    (refine, "OFFSET_START_HELD", False),
    (refine, "ROOT_DECIDES", False),
    (refine, "SCALED_TRIAL_KNOWN", False),
]
#: item 36: the forcing term in the loop's re-fits; item 37 (eighth session): the known anchors sit the phase out
_FORCING_OFF = [(field_fits, "STAGE_FORCING", None), (refine, "SIT_OUT", False)]
CONFIGS: dict[str, list[tuple[Any, str, Any]]] = {
    "before": [*_LOOP_OFF, (wire, "HELD_DOTS", False), (wire, "HELD_ACROSS_RUNS", False), *_ROUNDS_OFF, *_FORCING_OFF],
    "inner": [*_LOOP_OFF, *_ROUNDS_OFF, *_FORCING_OFF],
    "loop": [*_ROUNDS_OFF, *_FORCING_OFF],
    "rounds": _FORCING_OFF,
    "after": [(refine, "SIT_OUT", False)],  # the seventh session's end
    "sit_out": [],  # the defaults: item 37 too
}


def _workflow(k: int, place: str) -> list[dict[str, Any]]:
    """Every configuration of :data:`CONFIGS` on one workflow; each compared with the one before it."""
    rows, sols = [], {}
    for label, switches in CONFIGS.items():
        saved = [(module, name, getattr(module, name)) for module, name, _ in switches]
        for module, name, value in switches:
            setattr(module, name, value)
        try:
            sub, sol, row = _solve(k, place)
        finally:
            for module, name, value in saved:
                setattr(module, name, value)
        sols[label] = sol
        rows.append({"name": f"[78,{k}] {place}, {label}", **row})
        if len(sols) > 1:  # compared with the configuration before it
            b = sols[list(sols)[-2]]
            rows[-1]["max_position_change_m"] = float(np.max(np.abs(sol.positions_m - b.positions_m)))
            rows[-1]["same_exclusions"] = bool(np.array_equal(sol.excluded, b.excluded))
            rows[-1]["same_sigma"] = bool(np.array_equal(sol.sigma_m, b.sigma_m))
            rows[-1]["same_status"] = sol.status == b.status
            rows[-1]["bytes_saved_x"] = b.bytes / sol.bytes
    return rows


def main() -> None:
    global _STUDY
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--study", action="store_true")
    args = ap.parse_args()
    _STUDY = args.study
    _recording()
    economy._counting()
    rows = [row for k, place in (QUICK if args.quick else WORKFLOWS) for row in _workflow(k, place)]
    for label in CONFIGS:
        got = [r for r in rows if r["name"].endswith(label)]
        rows.append(
            {
                "name": f"all, {label}",
                "bytes": sum(r["bytes"] for r in got),
                "cg_its": sum(r["cg_its"] for r in got),
                "product_bytes": sum(r["product_bytes"] for r in got),
                "reduction_bytes": sum(r["reduction_bytes"] for r in got),
                "below_100x": sum(r["x_gather"] < 100 for r in got),
            }
        )
    write_json("uwb_inner", rows)
    print_table(f"inner solves (CG dots {wire.CG_DOT_DTYPE.__name__})", rows)


if __name__ == "__main__":
    main()

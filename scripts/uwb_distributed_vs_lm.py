#!/usr/bin/env python3
"""The distributed UWB solvers against LM on plant-like halls (docs/uwb.md, "Distributed solvers vs LM").

    PYTHONPATH=TREE/src python scripts/uwb_distributed_vs_lm.py FIRST LAST SOLVERS PLACEMENTS OUT.json
    # e.g. 0 12 N-CLM,N-CSG-TBLS,LM middle,corner /tmp/after.json ; then --summary OUT.json [OUT2.json ...]

Every hall is :func:`~distnav.models.uwb.hall.simulate_hall` with :data:`~distnav.models.uwb.hall.PLANT_LIKE`,
seed ``[78, k]``, solved by ``uwb solve``'s workflow (:func:`~distnav.models.uwb.field.solve_field`). For each
distributed solver: LM on the links it kept (same loss, σ, offsets), started at its answer, gives the reference
``x_LM`` and LM's central σ; the row records ``max |x − x_LM| / σ_LM`` over the free coordinates, the objectives,
the status, messages and bytes (precision included), the refinement's rounds / CG iterations / network
reductions, exclusions against the NLOS truth, and the 2σ coverage of the σ written (a-posteriori, the anchors
reported weak left out) and of LM's central σ on the same errors.
"""

from __future__ import annotations

import json
import sys
import time

import numpy as np

from distnav.algorithms.ranging import csg
from distnav.experiments.uwb_field import hall_problem
from distnav.models.uwb.field import FieldOptions, _solver_kwargs, prepare, solve_field, subset_measurements
from distnav.models.uwb.hall import PLANT_LIKE, HallConfig, simulate_hall


def measure(first: int, last: int, solvers: list[str], places: list[str]) -> list[dict]:
    rows = []
    for place in places:
        for k in range(first, last):
            h = simulate_hall(np.random.default_rng([78, k]), HallConfig().with_(known=place, **PLANT_LIKE))
            p, nlos = hall_problem(h)
            sub, geo = prepare(p)
            nl = nlos[geo.solvable[p.meas_a] & geo.solvable[p.meas_b]]
            for s in solvers:
                opts = FieldOptions(solver=s)
                t0 = time.process_time()
                sol = solve_field(sub, opts, geometry=geo)
                r = sol.result
                row = dict(
                    place=place,
                    k=k,
                    solver=s,
                    status=r.status,
                    its=int(r.iterations),
                    tot_its=sol.iterations,
                    msgs=sol.messages,
                    bytes=sol.bytes,
                    prec_msgs=sol.precision_messages,
                    cpu=time.process_time() - t0,
                    tp=int((sol.excluded & nl).sum()),
                    fp=int((sol.excluded & ~nl).sum()),
                    refine=r.settings.get("refine"),
                )
                free = sub.free
                weak = np.isin(np.array(sub.ids), list(sol.weak))
                err = np.abs(sol.positions_m - sub.truth_m)
                ok = free & ~weak[:, None] & np.isfinite(sol.sigma_m) & (sol.sigma_m > 0)
                d_est = (sol.positions_m - sub.truth_m)[sub.estimated]
                row.update(
                    cov_hit=int(np.sum(err[ok] <= 2 * sol.sigma_m[ok])),
                    cov_n=int(ok.sum()),
                    rmse=float(np.sqrt(np.mean(np.sum(d_est**2, 1)))),
                )
                if s != "LM":
                    kw = {**_solver_kwargs(FieldOptions(solver="LM")), "loss": opts.loss}
                    kept = subset_measurements(sub, ~sol.excluded).with_initial(np.asarray(r.estimates))
                    lm = csg.solve(kept, "LM", iterations=500, graduated=False, **kw)
                    sig, sig_post = lm.precision.std(a_posteriori=False), lm.precision.std(a_posteriori=True)
                    z = np.where(
                        free, np.abs(np.asarray(r.estimates) - lm.estimates) / np.where(sig > 0, sig, np.inf), 0.0
                    )
                    okl = ok & (sig_post > 0)
                    row.update(
                        zmax=float(z.max()),
                        obj=float(r.objective),
                        obj_lm=float(lm.objective),
                        lm_status=lm.status,
                        lm_cov_hit=int(np.sum(err[okl] <= 2 * sig_post[okl])),
                        lm_cov_n=int(okl.sum()),
                        ratio_med=float(np.median(sol.sigma_m[okl] / sig_post[okl])),
                    )
                rows.append(row)
                print(json.dumps(row), flush=True)
    return rows


def summary(paths: list[str]) -> None:
    for path in paths:
        rows = json.load(open(path))
        print("==", path)
        for place in ("middle", "corner"):
            for s in ("N-CLM", "N-CSG-TBLS", "LM"):
                R = [r for r in rows if r["place"] == place and r["solver"] == s]
                if not R:
                    continue
                cov = sum(r["cov_hit"] for r in R) / max(sum(r["cov_n"] for r in R), 1)
                line = (
                    f"{place:6s} {s:10s} n={len(R)} cov {cov:.3f} rmse {np.mean([r['rmse'] for r in R]):.3f} "
                    f"converged {sum(r['status'] == 'converged' for r in R)} msgs(median) "
                    f"{np.median([r['msgs'] for r in R]) / 1e3:.0f}k "
                    f"MB {np.median([r['bytes'] for r in R]) / 1e6:.0f}"
                    f" iterations {np.median([r['tot_its'] for r in R]):.0f} tp {sum(r['tp'] for r in R)} "
                    f"fp {sum(r['fp'] for r in R)}"
                )
                if s != "LM":
                    z = np.array([r["zmax"] for r in R])
                    lmc = sum(r["lm_cov_hit"] for r in R) / max(sum(r["lm_cov_n"] for r in R), 1)
                    line += (
                        f" | max z median {np.median(z):.3g} max {z.max():.3g} | F/F_LM median "
                        f"{np.median([r['obj'] / r['obj_lm'] for r in R]):.3f} | LM σ cov {lmc:.3f} | σ/σ_LM "
                        f"{np.median([r['ratio_med'] for r in R]):.2f}"
                    )
                    rf = [r["refine"] for r in R if r["refine"]]
                    if rf:
                        line += (
                            f" | refine rounds {np.median([x['rounds'] for x in rf]):.0f} CG "
                            f"{np.median([x['cg_iterations'] for x in rf]):.0f} reductions "
                            f"{np.median([x['reductions'] for x in rf]):.0f}"
                        )
                print(line)


if __name__ == "__main__":
    if sys.argv[1] == "--summary":
        summary(sys.argv[2:])
    else:
        out = measure(int(sys.argv[1]), int(sys.argv[2]), sys.argv[3].split(","), sys.argv[4].split(","))
        json.dump(out, open(sys.argv[5], "w"), indent=1)

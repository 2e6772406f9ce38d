"""The rows issue 31 added to the claims table, on small synthetic results dicts: each says "agree" on values that
meet the paper's statement and "differ" when one value breaks it (the verdict is computed, never typed), and a
missing field makes the row "not checkable" with its claim kept."""

from __future__ import annotations

import copy
from typing import Any

import numpy as np
import pytest

from distnav.experiments.claims_paper000 import admm, codebias, qc
from distnav.experiments.claims_paper002 import settle_iteration, uwb, uwb_horizontal
from distnav.experiments.claims_paper003 import ckf, ionosphere

PROBLEMS = ("GC", "GO", "GM", "LC", "LO", "LM", "RC", "RM")
SOLVERS = ("LM", "CSG", "N-CSG", "N-CSG-BLS", "N-CSG-TBLS", "N-CLM")
# final RMSE [m] and RMS cost per solver, and the time constant of its decay [iterations]
FINAL = {"LM": (1.5, 0.1, 5), "CSG": (0.9, 0.5, 40), "N-CSG": (0.6, 0.4, 15), "N-CSG-BLS": (0.4, 0.2, 15)}
FINAL |= {"N-CSG-TBLS": FINAL["N-CSG-BLS"], "N-CLM": (0.45, 0.25, 15)}
PLACEMENT = {"C": 0.0, "O": -0.01, "M": 0.05}  # distributed offsets: O ≲ C < M
LM_PLACEMENT = {"C": 0.0, "O": -0.1, "M": 0.4}  # LM's spread larger


def _row(rows: list[dict[str, Any]], text: str) -> dict[str, Any]:
    found = [r for r in rows if text in r["claim"]]
    assert len(found) == 1, (text, [r["claim"] for r in rows])
    return found[0]


def uwb_results(iterations: int = 220) -> dict[str, Any]:
    k = np.arange(iterations + 1)
    table, curves = [], {}
    for p in PROBLEMS:
        curves[p] = {}
        for s in SOLVERS:
            e, c, tau = FINAL[s]
            off = (LM_PLACEMENT if s == "LM" else PLACEMENT)[p[1]]
            e, c = e + off, c + off
            rmse = e + 4.0 * np.exp(-k / tau)
            cost = c + 10.0 * np.exp(-k / tau)
            if p[0] == "R" and s in ("N-CSG", "N-CSG-TBLS"):
                cost = cost + 1e-3 * (k % 2)  # a small sawtooth: rises every other iteration
            curves[p][s] = {"rmse_m": rmse.tolist(), "rms_cost": cost.tolist()}
            if "LS" in s:
                curves[p][s]["step_size"] = (1.2e-3 * (1 - np.exp(-k / 10))).tolist()
            table.append({"problem": p, "solver": s, "rmse_m": rmse[-1], "rms_cost": cost[-1], "diverged": 0})
    return {"settings": {"iterations": iterations}, "table": table, "curves": curves}


def _set_final(r: dict[str, Any], problem: str, solver: str, key: str, value: float) -> None:
    for row in r["table"]:
        if row["problem"] == problem and row["solver"] == solver:
            row[key] = value
    curves = r["curves"][problem][solver][key]
    curves[-1] = value


UWB_ROWS = {
    "LM's error stays above 1 m": lambda r: _set_final(r, "GC", "LM", "rmse_m", 0.8),
    "CSG is considerably slower": lambda r: _set_final(r, "LC", "CSG", "rmse_m", 0.3),
    "LM's cost settles in under 50": lambda r: r["curves"]["RM"]["LM"].update(
        rms_cost=(0.1 + 10.0 * np.exp(-np.arange(221) / 40)).tolist()
    ),
    "settle in under 100 iterations except on class L": lambda r: r["curves"]["GO"]["N-CLM"].update(
        rms_cost=(0.25 + 10.0 * np.exp(-np.arange(221) / 60)).tolist()
    ),
    "with a line search beats": lambda r: _set_final(r, "RM", "N-CSG-BLS", "rms_cost", 5.0),
    "oscillate in cost": lambda r: r["curves"]["RC"]["N-CSG-BLS"].update(
        rms_cost=(np.asarray(r["curves"]["RC"]["N-CSG-TBLS"]["rms_cost"])).tolist()
    ),
    "change only slightly from iteration 100": lambda r: r["curves"]["RC"]["N-CSG-TBLS"].update(
        step_size=np.linspace(1e-4, 1.3e-3, 221).tolist()
    ),
    "opposite corners negligibly better": lambda r: [_set_final(r, "GC", s, "rmse_m", 3.5) for s in SOLVERS[1:]],
    "matters more for LM": lambda r: [_set_final(r, p, "LM", "rmse_m", 1.5) for p in ("LC", "LO", "LM")],
    "class R: fixed anchors in a corner": lambda r: _set_final(r, "RC", "CSG", "rms_cost", 50.0),
    "below 50 cm for most problems": lambda r: [
        _set_final(r, p, s, "rmse_m", 0.7) for p in PROBLEMS[:5] for s in ("N-CSG-BLS", "N-CSG-TBLS", "N-CLM")
    ],
    "on class L every solver reduces": lambda r: r["curves"]["LO"]["CSG"]["rmse_m"].__setitem__(50, 9.0),
    "reach the lowest error and cost": lambda r: _set_final(r, "GM", "N-CSG", "rmse_m", 0.1),
}


def test_uwb_rows_agree_on_values_that_meet_the_paper():
    rows = uwb(uwb_results())
    for text in UWB_ROWS:
        assert _row(rows, text)["verdict"] == "agree", _row(rows, text)
    assert _row(rows, "class M (measured office)")["verdict"] == "not checkable"
    assert _row(rows, "ambiguity can make estimates")["verdict"] == "not checkable"


@pytest.mark.parametrize("text", list(UWB_ROWS))
def test_each_uwb_row_says_differ_when_one_value_breaks_it(text):
    r = uwb_results()
    UWB_ROWS[text](r)
    row = _row(uwb(r), text)
    assert row["verdict"] == "differ", row


def test_uwb_rows_about_late_iterations_are_not_checkable_on_a_short_run():
    rows = uwb(uwb_results(iterations=60))
    for text in ("settle in under 100 iterations", "change only slightly from iteration 100"):
        row = _row(rows, text)
        assert row["verdict"] == "not checkable" and "60 iterations" in row["why"]
    assert _row(uwb({}), "LM's error stays above 1 m")["verdict"] == "not checkable"  # claim kept, field named
    assert "results.json lacks" in _row(uwb({}), "LM's error stays above 1 m")["why"]


def test_settle_iteration_reads_the_band_of_the_final_value():
    c = np.array([10.0, 5.0, 2.0, 1.2, 1.04, 1.0])  # band 5 % of 9 = 0.45: within from index 3 on
    assert settle_iteration(c) == 3
    assert settle_iteration(np.array([1.0, 2.0])) is None and settle_iteration(np.array([3.0, np.nan])) is None


def test_uwb_horizontal_has_the_fifty_centimetre_row():
    r = uwb_results()
    r["settings"]["start"] = "horizontal"
    r["checks"] = {"mean_line_search_RMSE_by_class_m": {"G": 0.3, "L": 0.7, "R": 0.5}}
    rows = uwb_horizontal(r)
    assert _row(rows, "below 50 cm for most problems (start perturbed")["verdict"] == "agree"
    assert "start: horizontal" in _row(rows, "below 50 cm")["why"]


# ------------------------------------------------------------------------------------------------ paper 000
def admm_results() -> dict[str, Any]:
    sets = {
        "C_full": ([1, 3, 4, 6, 9], []),
        "C_reduced": ([1, 3, 4, 9], [[5, 6], [6, 7]]),
        "C_all": (list(range(1, 10)), []),
    }
    return {
        "fig5_conditions_18": {
            k: {
                "nodes_1_based": n,
                "conditions_18_hold": True,
                "unused_links_1_based": u,
                "final_relative_distance_to_blue": 1e-12,
            }
            for k, (n, u) in sets.items()
        },
        "fig6_as_printed": {
            "rho": 1.0,
            "iterations": 400,
            "fig5_graph_fig6": 1e-12,
            "fig5_graph_lagrangian": 1e-12,
            "regular_ring_fig6": 1e-14,
            "fig5_graph_c_i": [1, 2, 2, 1, 3, 2, 3, 3, 1],
        },
    }


def test_admm_rows_conditions_18_and_fig6_as_printed():
    r = admm_results()
    rows = admm(r)
    assert _row(rows, "C = {1,3,4,9} satisfies")["verdict"] == "agree"
    assert _row(rows, "C = {1,2,3,4,5,6,7,8,9} satisfies")["verdict"] == "agree"
    assert _row(rows, "Fig. 6 as printed")["verdict"] == "agree"  # would the printed form reach the BLUE
    bad = copy.deepcopy(r)
    bad["fig5_conditions_18"]["C_reduced"]["unused_links_1_based"] = [[5, 6]]
    bad["fig5_conditions_18"]["C_all"]["final_relative_distance_to_blue"] = 1e-3
    bad["fig6_as_printed"]["fig5_graph_fig6"] = 5e-3  # biased on the irregular graph: the paper's "= BLUE" fails
    rows = admm(bad)
    assert _row(rows, "C = {1,3,4,9} satisfies")["verdict"] == "differ"
    assert _row(rows, "C = {1,2,3,4,5,6,7,8,9} satisfies")["verdict"] == "differ"
    assert _row(rows, "Fig. 6 as printed")["verdict"] == "differ"
    assert "0.005" in _row(rows, "Fig. 6 as printed")["distnav_value"]  # the value comes from the results
    other = copy.deepcopy(r)
    other["fig5_conditions_18"]["C_reduced"]["nodes_1_based"] = [1, 3, 4, 6]  # (18) holds, but not the paper's C
    assert _row(admm(other), "C = {1,3,4,9} satisfies")["verdict"] == "differ"


def codebias_results() -> dict[str, Any]:
    return {
        "epochs": 300,
        "iterations": 1000,
        "rho_scale": "epoch",
        "iterations_to_1e-3": {"5": None, "0.5": 250, "0.05": None, "0.005": None},
        "iterations_to_1e-3_rho_scale_session": {"5": 400, "0.5": None, "0.05": None, "0.005": None},
        "final_max_distance_m": {"5": 0.3, "0.5": 1e-4, "0.05": 0.02, "0.005": 0.1},
        "fig8_recursive_sigma": {
            "first_epoch_m": {"G01": 0.5, "G24": 0.9},
            "last_epoch_m": {"G01": 0.02, "G24": 0.03},
            "epochs_where_sigma_grew": {"G01": 0, "G24": 0},
        },
    }


def test_codebias_rows_fig8_bands_and_slow_rho_5_and_the_rho_choice():
    r = codebias_results()
    rows = codebias(r)
    assert _row(rows, "3σ intervals")["verdict"] == "agree"
    slow = _row(rows, "ρ = 5 converges very slowly")
    assert slow["verdict"] == "agree" and "rho_scale = epoch" in slow["why"] and "5: 400" in slow["why"]
    fastest = _row(rows, "ρ = 0.5 is the fastest")
    assert fastest["verdict"] == "agree" and "agrees only under distnav's choice" in fastest["why"]
    r["fig8_recursive_sigma"]["epochs_where_sigma_grew"]["G24"] = 3
    r["iterations_to_1e-3"]["5"] = 900
    rows = codebias(r)
    assert _row(rows, "3σ intervals")["verdict"] == "differ"
    assert _row(rows, "ρ = 5 converges very slowly")["verdict"] == "differ"
    assert _row(rows, "ρ = 0.5 is the fastest")["verdict"] == "agree"  # 250 < 900


def qc_results() -> dict[str, Any]:
    return {
        "network": {"n_nodes": 110},
        "injected": [1, 2, 3],
        "gross_error_sigma": 6.0,
        "level": 0.001,
        "distributed": {"removed": [2, 1, 3], "variance_factor": 0.95, "extra_iterations": 10, "extra_messages": 99},
        "centralized": {"removed": [2, 1, 3], "variance_factor": 0.95},
        "same_removals": True,
        "max_abs_w_difference": 1e-9,
        "covariance_relative_error_vs_final_centralized": 1e-9,
        "max_distance_to_clean_centralized_m": {"no_snooping": 0.4, "distributed": 0.03, "centralized": 0.03},
        "ckf": {
            "setup": {"trials": 20, "gross_errors_per_trial": 6, "gross_error_sigma": 8.0, "level": 0.001, "k_n": 6},
            "detection_rate": {"distributed": 0.98, "central": 1.0},
            "false_alarm_rate": {"distributed": 0.0012, "central": 0.0012},
            "final_distance_to_clean_ckf": {"distributed": {"median": 0.02}, "untested": {"median": 0.1}},
            "node_local_precision": {
                "exact_min_ratio": 1.0,
                "exact_max_ratio": 1.0 + 1e-13,
                "bound_min_ratio": 1.08,
                "exact_extra_bytes_fraction": 0.9,
                "bound_extra_bytes_fraction": 0.4,
            },
        },
    }


QC_BREAKS = {
    "removes what centralized data snooping removes": lambda r: r.update(same_removals=False),
    "distributed precision (covariance": lambda r: r.update(covariance_relative_error_vs_final_centralized=1e-3),
    "as close to the clean one": lambda r: r["max_distance_to_clean_centralized_m"].update(distributed=0.2),
    "own precision": lambda r: r["ckf"]["node_local_precision"].update(bound_min_ratio=0.9),
    "detect gross errors as well": lambda r: r["ckf"]["detection_rate"].update(distributed=0.8),
    "tested CKF ends closer": lambda r: r["ckf"]["final_distance_to_clean_ckf"]["distributed"].update(median=0.2),
}


@pytest.mark.parametrize("text", list(QC_BREAKS))
def test_qc_rows_agree_then_differ(text):
    r = qc_results()
    assert _row(qc(r), text)["verdict"] == "agree"
    QC_BREAKS[text](r)
    assert _row(qc(r), text)["verdict"] == "differ"


def test_qc_without_the_ckf_half_has_only_the_admm_rows():
    r = qc_results()
    del r["ckf"]
    assert {row["paper"] for row in qc(r)} == {"000"} and len(qc(r)) == 3


# ------------------------------------------------------------------------------------------------ paper 003
def test_ckf_exact_average_row():
    r = {"exact_average_vs_central": {"max_relative_estimate_difference": 1e-15, "max_std_ratio_minus_1": 1e-15}}
    assert _row(ckf(r), "with exact averages")["verdict"] == "agree"
    r["exact_average_vs_central"]["max_std_ratio_minus_1"] = 0.2
    assert _row(ckf(r), "with exact averages")["verdict"] == "differ"


def _box(v: float) -> dict[str, float]:
    return {"min": v, "p25": v + 5, "median": v + 10, "p75": v + 15, "max": v + 20}


def ionosphere_results() -> dict[str, Any]:
    degrees = [2, 3, 2, 6, 4, 4, 6, 6, 6, 4, 4, 3, 2]
    per_rx = [1.3, 1.2, 1.4, 1.01, 1.2, 1.15, 1.02, 1.03, 1.04, 1.1, 1.1, 1.3, 1.45]
    best = {"4", "7", "8", "9"}
    ckf_boxes = {
        str(k): {str(i + 1): _box(40.0 + (1 if str(i + 1) in best else gap)) for i in range(13)}
        for k, gap in ((4, 30.0), (6, 10.0), (12, 2.0))
    }
    return {
        "scenario": {
            "receivers": 13,
            "links": [[0, 1], [0, 5], [1, 6], [2, 3]],
            "degrees": degrees,
            "kn": [4, 6, 12],
            "n_epochs": 960,
            "satellites_rising_twice": ["G02", "G06", "G16", "G17", "G19", "G26", "G32"],
            "visibility_epochs": {"G21": 100, "G22": 900, "G05": 500},
        },
        "ckf_to_central_vtec_max_per_receiver": {"4": per_rx},
        "ckf_to_central_ratio_max": {"4": 1.5, "12": 1.05},
        "local_to_central_after_1h": {"all_receivers_range": [2.2, 3.4]},
        "dcb_time_to_0.5ns_min": {"central": _box(40.0), "ckf": ckf_boxes},
    }


IONO_BREAKS = {
    "receiver 1 is linked to 2 and 6": lambda r: r["scenario"]["links"].append([0, 2]),
    "set and re-rise": lambda r: r["scenario"].update(satellites_rising_twice=["G02"]),
    "visible longest": lambda r: r["scenario"]["visibility_epochs"].update(G05=950),
    "receivers 4, 7, 8, 9 (most neighbours) are best": lambda r: r["ckf_to_central_vtec_max_per_receiver"][
        "4"
    ].__setitem__(5, 1.0),
    "better than the local filter": lambda r: r["ckf_to_central_ratio_max"].update({"4": 2.5}),
    "approach the central one": lambda r: r["dcb_time_to_0.5ns_min"]["ckf"]["12"]["1"].update(max=200.0),
    "almost the central boxplot": lambda r: r["dcb_time_to_0.5ns_min"]["ckf"]["4"]["7"].update(median=80.0),
}


@pytest.mark.parametrize("text", list(IONO_BREAKS))
def test_ionosphere_rows_agree_then_differ(text):
    r = ionosphere_results()
    assert _row(ionosphere(r), text)["verdict"] == "agree", _row(ionosphere(r), text)
    IONO_BREAKS[text](r)
    assert _row(ionosphere(r), text)["verdict"] == "differ"


def test_notes_carry_the_runs_numbers_not_typed_ones():
    r = ionosphere_results()
    r["scenario"]["n_epochs"] = 123
    r["local_to_central_after_1h"] |= {"vtec": [1.6, 2.9], "grad_lat": [1.8, 2.2], "grad_lon": [2.0, 2.7]}
    row = _row(ionosphere(r), "ratio of ν_o between 1.5 and 3")
    assert "123 epochs" in row["why"] and "1.6–2.9" == row["distnav_value"]


def test_setup_and_illustration_rows_are_stated_not_measured():
    rows = ckf({}) + admm({}) + uwb({})
    illustrations = [r for r in rows if r["paper_value"] == "illustration"]
    assert len(illustrations) == 5 and all(r["verdict"] == "not checkable" for r in illustrations)
    assert all("not in results.json" in r["why"] for r in illustrations)
    tested = [r for r in rows if r["paper_value"] == "algorithm"]
    assert tested and all(r["verdict"] == "agree" and r["test"] for r in tested)


def test_a_claims_table_row_by_row_a_missing_field_keeps_the_claim_and_names_the_field():
    from distnav.experiments.claims import Claim, get, rows_from, stated

    def value(r: dict[str, Any]) -> tuple[Any, bool | None, str]:
        return get(r, "a", "b"), get(r, "a", "b") > 2, "w"

    table = (
        Claim("§5", "t", 1, "x", value),
        Claim("§6", "u", 2, "", value),
        Claim("Fig. 1", "v", "illustration", "", stated("not in results.json: why")),
    )
    lacks = {"distnav_value": None, "verdict": "not checkable", "test": "", "why": "results.json lacks 'a.b'"}
    rows = rows_from("002", table, {"a": {}})
    assert rows[0] == {"paper": "002", "where": "§5", "claim": "t", "paper_value": 1} | lacks
    assert rows[1] == {"paper": "002", "where": "§6", "claim": "u", "paper_value": 2} | lacks
    stated_row = {"paper": "002", "where": "Fig. 1", "claim": "v", "paper_value": "illustration"}
    assert rows[2] == stated_row | lacks | {"why": "not in results.json: why"}
    rows = rows_from("002", table, {"a": {"b": 3}})
    assert [(r["distnav_value"], r["verdict"], r["test"], r["why"]) for r in rows[:2]] == [
        (3, "agree", "x", "w"),
        (3, "agree", "", "w; no test pins it yet"),  # a measured row no test pins says so
    ]
    assert rows_from("002", table, {"a": {"b": 1}})[0]["verdict"] == "differ"


# ------------------------------------------------------------------------------------------------ docs12: §5 rows
def test_rmse_stays_gradual_under_the_cost_oscillation_on_class_r():
    r = uwb_results()  # N-CSG and N-CSG-TBLS have a cost sawtooth on class R, a smooth RMSE
    row = _row(uwb(r), "do not show in the RMSE")
    # the sawtooth's +1e-3 outweighs the decay 10 e^(-k/15) (1 - e^(-1/15)) from k = 98 on: even k = 98…218
    assert row["verdict"] == "agree" and "RC N-CSG: RMSE rises 0, cost 61 times" in row["distnav_value"]
    r["curves"]["RM"]["N-CSG-TBLS"]["rmse_m"] = (
        np.asarray(r["curves"]["RM"]["N-CSG-TBLS"]["rmse_m"]) + 1e-3 * (np.arange(221) % 2)
    ).tolist()
    assert _row(uwb(r), "do not show in the RMSE")["verdict"] == "differ"
    r = uwb_results()
    next(row for row in r["table"] if (row["problem"], row["solver"]) == ("RM", "N-CSG"))["diverged"] = 5
    assert "RM N-CSG: RMSE rises 0, cost 61 times (5 blew up)" in _row(uwb(r), "do not show in")["distnav_value"]
    r["curves"]["RC"]["N-CSG"]["rmse_m"][-1] = None  # blew up: no gradual decrease to speak of
    assert "RC N-CSG: no curve (blew up)" in _row(uwb(r), "do not show in the RMSE")["distnav_value"]


def test_still_improving_at_the_last_iteration_needs_500_iterations_and_a_falling_tail():
    assert _row(uwb(uwb_results()), "do not fully stop")["verdict"] == "not checkable"  # 220 iterations
    r = uwb_results(iterations=500)  # decay constants of 15 iterations: flat (to 1e-12) over the last 50
    assert _row(uwb(r), "do not fully stop")["verdict"] == "differ"
    k = np.arange(501)
    for p in PROBLEMS:
        for s in ("N-CSG", "N-CSG-BLS", "N-CSG-TBLS", "N-CLM"):
            r["curves"][p][s]["rms_cost"] = (0.2 + 10.0 / (1.0 + k)).tolist()  # still falling at 500
    row = _row(uwb(r), "do not fully stop")
    assert row["verdict"] == "agree" and row["distnav_value"].count("8 of 8") == 4
    r["curves"]["GC"]["N-CLM"]["rms_cost"] = (0.2 + 10.0 * np.exp(-k / 15.0)).tolist()
    for p in ("GO", "GM", "LC", "LO"):
        r["curves"][p]["N-CLM"]["rms_cost"] = r["curves"]["GC"]["N-CLM"]["rms_cost"]
    assert _row(uwb(r), "do not fully stop")["verdict"] == "differ"  # N-CLM flat on 5 of 8


def test_every_solver_hardest_on_the_ladder():
    r = uwb_results()
    row = _row(uwb(r), "highest error on class L")
    assert row["verdict"] == "differ" and "LM R" in row["distnav_value"]  # synthetic: R's placements worst
    for p in ("LC", "LO", "LM"):
        for s in SOLVERS:
            _set_final(r, p, s, "rmse_m", 5.0)
    row = _row(uwb(r), "highest error on class L")
    assert row["verdict"] == "agree" and row["distnav_value"].endswith("N-CLM L")
    _set_final(r, "RC", "CSG", "rmse_m", float("nan"))  # blew up in every instance: counted worst
    assert "CSG R" in _row(uwb(r), "highest error on class L")["distnav_value"]


def test_fig8_stability_row_is_stated_not_measured():
    row = _row(codebias(codebias_results()), "rather stable over time")
    assert row["verdict"] == "not checkable" and "not the solution's series" in row["why"]


def test_line_search_comparable_to_nclm_within_ten_per_cent():
    r = uwb_results()  # BLS/TBLS end at 0.4 m / cost 0.2 + offset, N-CLM at 0.45 / 0.25: 12–20 % apart
    assert _row(uwb(r), "comparable to N-CLM")["verdict"] == "differ"
    for p in PROBLEMS:
        for s in ("N-CSG-BLS", "N-CSG-TBLS"):
            _set_final(r, p, s, "rmse_m", 1.05 * final_of(r, p, "N-CLM", "rmse_m"))
            _set_final(r, p, s, "rms_cost", 0.95 * final_of(r, p, "N-CLM", "rms_cost"))
    row = _row(uwb(r), "comparable to N-CLM")
    assert (
        row["verdict"] == "agree" and row["distnav_value"] == "largest difference from N-CLM: RMSE 5.0%, RMS cost 5.0%"
    )


def final_of(r: dict[str, Any], problem: str, solver: str, key: str) -> float:
    return next(row[key] for row in r["table"] if (row["problem"], row["solver"]) == (problem, solver))

"""The field workflow pieces: the per-anchor exclusion check (swamping undone), the gather-at-one-anchor
communication count (hand-counted on a chain), and the experiment's quick variant end to end."""

from __future__ import annotations

import numpy as np

from distnav.models.uwb.field import RANGE_RECORD_BYTES, gather_cost
from distnav.models.uwb.local import fit_anchor, repair_exclusions
from distnav.models.uwb.problems import build_problem


def _star(bias_on: int):
    """Anchor X (2-D) ranged by 4 known anchors; link ``bias_on`` is 1.5 m too long (NLOS)."""
    known = {"K0": [0.0, 0.0], "K1": [10.0, 0.0], "K2": [10.0, 10.0], "K3": [0.0, 10.0]}
    x = np.array([3.0, 4.0])
    links, r = [], []
    for k, (name, q) in enumerate(known.items()):
        links.append(("X", name))
        r.append(float(np.linalg.norm(x - q)) + (1.5 if k == bias_on else 0.0))
    ids = ["X", *known]
    pos = np.array([x, *known.values()])
    return build_problem(ids, links, r, fixed=known, dim=2, truth_m=pos, initial_m=pos), x


def test_fit_anchor_recovers_the_position_without_the_nlos_link():
    p, x = _star(bias_on=2)
    start = p.truth_m.copy()
    start[0] += [2.0, -1.0]
    est, rms = fit_anchor(p, 0, start, [0, 1, 3])
    assert np.allclose(est, x, atol=1e-6) and rms < 1e-6
    _, rms_bad = fit_anchor(p, 0, p.truth_m, [0, 1, 2, 3])
    assert rms_bad > 0.1


def test_repair_swaps_a_swamped_exclusion_for_the_nlos_link():
    p, _ = _star(bias_on=2)
    wrong = np.array([True, True, False, False])  # the global fit excluded two good links
    new, notes = repair_exclusions(p, p.truth_m, wrong, np.zeros(4, bool))
    assert new.tolist() == [False, False, True, False] and len(notes) == 1 and "X-K2" in notes[0]
    right = np.array([False, False, True, False])
    same, notes = repair_exclusions(p, p.truth_m, right, np.zeros(4, bool))
    assert same.tolist() == right.tolist() and notes == []


def test_gather_cost_on_a_chain_is_hand_counted():
    # A - B - C - D - E in a line (4 links), A and B known, 2-D: the best sink is C (the middle)
    ids = list("ABCDE")
    pos = np.array([[0.0, 0.0], [1.0, 0.2], [2.0, 0.0], [3.0, 0.3], [4.0, 0.0]])
    links = [("A", "B"), ("B", "C"), ("C", "D"), ("D", "E"), ("A", "C"), ("B", "D"), ("C", "E")]
    d = [float(np.linalg.norm(pos[ids.index(a)] - pos[ids.index(b)])) for a, b in links]
    p = build_problem(ids, links, d, fixed={"A": pos[0], "B": pos[1]}, dim=2)
    g = gather_cost(p)
    # sink C: record hops = min(hop(a), hop(b)) per link: AB 1, BC 0, CD 0, DE 1, AC 0, BD 1, CE 0 -> 3
    # positions back: C, D, E estimated at hops 0, 1, 1 -> 2 × 2 coordinates × 8 B
    assert g["sink"] == "C" and g["bytes_ranges"] == 3 * RANGE_RECORD_BYTES and g["bytes_positions"] == 2 * 2 * 8
    assert g["messages"] == 2 * (5 - 1) and g["links"] == 7


def test_uwb_field_quick_variant_runs(tmp_path):
    from distnav.experiments import load
    from distnav.experiments.common import ExperimentContext

    mod = load("uwb-field")
    ctx = ExperimentContext(out_dir=tmp_path, quick=True, options={"instances": 1, "solvers": ["LM"]})
    res = mod.run(ctx)
    rows = {r["placement"]: r for r in res["table"]}
    assert set(rows) == {"middle", "corner"}
    for r in rows.values():
        assert r["oracle_rmse_m"] < 0.2 and r["recall"] is not None and r["statuses"]
    assert (tmp_path / "results.json").is_file() and (tmp_path / "table.md").is_file()


def test_weak_anchor_when_its_kept_links_still_misfit_or_are_too_few():
    from distnav.models.uwb.field import weak_anchors

    known = {"K0": [0.0, 0.0], "K1": [10.0, 0.0], "K2": [10.0, 10.0], "K3": [0.0, 10.0], "K4": [5.0, -3.0]}
    links = [(u, k) for u in ("X", "Y", "Z") for k in known]  # 5 links each, 2 free coordinates each
    p = build_problem(["X", "Y", "Z", *known], links, np.full(15, 5.0), fixed=known, dim=2)
    none = np.zeros(15, bool)
    excl = none.copy()
    excl[2] = True  # X-K2 excluded: 4 links kept
    fits = np.full(15, 0.01)
    assert weak_anchors(p, fits, excl, none) == ()  # X's kept links fit: not weak
    misfit = fits.copy()
    misfit[[0, 1, 3]] = [0.5, -0.5, 0.4]  # X's kept links still 0.4 m RMS off
    assert weak_anchors(p, misfit, excl, none) == ("X",)
    assert weak_anchors(p, misfit, none, none) == ()  # nothing excluded or flagged
    two = excl.copy()
    two[7] = True  # Y-K2 excluded too, and Y-K3: Y keeps 3 links = one redundant link only
    two[8] = True
    assert weak_anchors(p, fits, two, none) == ("Y",)

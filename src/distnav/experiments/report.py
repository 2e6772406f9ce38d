"""The demo report: ``index.html`` (and ``REPORT.md``) for a reviewer.

At the top, the table of every paper claim the run can check (:mod:`distnav.experiments.claims_table`: the paper's
statement, distnav's number, agree / differ / not checkable, why) and what the quick variants change. Then one
section per experiment: its key numbers with the paper's value beside each (the ``(paper …)`` part of a headline
label, or "not stated"), its claims, and every figure with a caption, linked to the full-size PNG.
"""

from __future__ import annotations

import html
import json
import re
import struct
from pathlib import Path
from typing import Any

from distnav import __version__
from distnav.experiments.claims import AGREE, DIFFER, NOT_CHECKABLE
from distnav.experiments.claims_table import claims_for, counts, html_table, markdown_table
from distnav.output import atomic_write_text, to_jsonable

__all__ = [
    "write_report",
    "legend_lines",
    "table_lines",
    "STATUS_MEANINGS",
    "VERDICT_MEANINGS",
    "FIGURE_CAPTIONS",
    "QUICK_NOTES",
    "PAPER_VALUES",
    "paper_value",
    "split_paper_value",
    "caption",
]

#: One caption per figure an experiment writes (an experiment module may define its own ``FIGURE_CAPTIONS``).
FIGURE_CAPTIONS: dict[str, dict[str, str]] = {
    "consensus": {
        "fig2_networks.png": "Paper 003 Fig. 2. (a) The static network, 20 nodes and 49 links (the stored paper-like "
        "network: its λ values and probabilities are the paper's); (b) the switching network, 4 sessions with 7, 6, "
        "8, 7 links, every node with at most one neighbour per session.",
        "fig3_iterations.png": "Paper 003 Fig. 3. Twenty values with average 5 iterated 30 times: Protocols 1–3 on "
        "network (a), Protocol 4 on network (b). P1 and P3 converge fastest, P2 slowest, as in the paper.",
        "fig4_probability.png": "Paper 003 Fig. 4. Probability (eq. 40) that every node is within qσ of the average "
        "after k_n = 10, 20, 30 rounds, by Monte Carlo. Paper at q = 0.2: P1 ≈ 80 %, P2 < 5 % (k_n = 10); P2 ≈ 80 %, "
        "P1 and P3 ≈ 100 % (k_n = 30); P3 highest, P2 lowest, P4 above P2.",
    },
    "admm": {
        "fig3_method_of_multipliers.png": "Paper 000 Fig. 3. Two nodes, scalar x: the method of multipliers' "
        "iterates (left) stay on the dual-feasibility line and climb the dual function g(u) (right) monotonically.",
        "fig4_admm_vs_multipliers.png": "Paper 000 Fig. 4. ADMM from z⁰ = 3 and −7 against the method of "
        "multipliers: ADMM leaves the feasibility line and its g(u) need not rise (z⁰ = −7 drops once, the "
        "paper's magenta triangles).",
        "fig5_constraint_nodes.png": "Paper 000 Fig. 5. The 9-node network with C = {1,3,4,6,9} and C = {1,3,4,9} "
        "(dotted: links the reduced set leaves unused) and the convergence of both to the BLUE. The paper says the "
        "reduced set is never faster; distnav finds that true only for small ρ (docs/admm.md).",
        "fig9_rho.png": "Paper 000 Fig. 9 analogue on a random network: iterations to 1e-6 against ρ (both too "
        "small and too large ρ slow ADMM down) and every node's distance to the BLUE.",
        "fig_nonlinear_ranges.png": "Paper 000 §4.3: range positioning with the linearized and the nonlinear "
        "(eq. 23) ADMM, both reaching the centralized Gauss–Newton solution.",
    },
    "ckf": {
        "std_ratio_time.png": "Paper 003 §4: the CKF's standard deviations (Fig. 7 recursion) divided by the central "
        "filter's, per node over time, for several k_n; nodes with few neighbours are furthest from 1.",
        "std_ratio_vs_degree.png": "Largest CKF/central std ratio at the last epoch against the node degree: "
        "poorly connected nodes gain least from a few consensus rounds (paper 003 §5.4).",
        "alpha.png": "Paper 003 eq. (46): α = n Σ_j l_ij² ≥ 1, the stationary variance inflation of the CKF, "
        "falling to 1 as the number of rounds k_n grows.",
    },
    "uwb": {
        "fig3_rmse.png": "Paper 002 Fig. 3. Mean RMSE of the anchor positions over the iterations, per problem "
        "class and solver.",
        "fig4_cost.png": "Paper 002 Fig. 4. Mean RMS cost over the iterations; LM reaches the lowest cost.",
        "fig5_examples.png": "Paper 002 Fig. 5. First instance of each class: true and estimated anchors in x–y, "
        "and the heights (a planar network leaves the height sign ambiguous).",
        "fig6_step_size.png": "Paper 002 Fig. 6. Mean line-search step α of N-CSG-BLS and N-CSG-TBLS (paper: "
        "≈ 1.2e-3 / 1.3e-3); distnav's two searches visit the same steps, so the curves coincide.",
    },
    "codebias": {
        "fig7_network.png": "Paper 000 Fig. 7. The synthetic IGS-like network: 110 stations, 118 links, the 9 hubs "
        "as constraint nodes (the paper's counts).",
        "fig8_centralized.png": "Paper 000 Fig. 8. Recursive centralized code-bias solutions of two satellites with "
        "3σ bands, against the simulated truth.",
        "fig9_rho.png": "Paper 000 Fig. 9. ADMM's distance to the centralized solution for ρ = 5, 0.5, 0.05, 0.005 "
        "(paper: 0.5 fastest, 5 very slow).",
        "fig10_init.png": "Paper 000 Fig. 10. ρ = 0.5 from different initial values: zero, ±5 m, a previous "
        "solution (paper: the previous solution converges fastest).",
        "fig11_per_node.png": "Paper 000 Fig. 11. Per-node differences x_i − x̂ of the best and the worst tracked "
        "satellite (paper: the well-tracked one converges faster).",
    },
    "ckf-ionosphere": {
        "fig08_10_network_visibility.png": "Paper 003 Figs. 8 and 10. The 13-receiver Perth network and the "
        "satellite visibility (synthetic constellation, not the real sky of 2 June 2016).",
        "fig11_central_vs_local.png": "Paper 003 Fig. 11. Standard deviations of the central and single-receiver "
        "filters and their ratio (paper: √13 at the start, 1.5–3 after one hour).",
        "fig12_ckf_to_central.png": "Paper 003 Fig. 12. CKF/central std ratio per receiver for k_n = 4, 6, 12 "
        "(paper: close to 1 at k_n = 12; receivers with few neighbours worst at k_n = 4).",
        "fig13_dcb_time_boxplots.png": "Paper 003 Fig. 13. Minutes until each DCB's std falls below 0.5 ns, per "
        "filter and k_n (paper, central: 7 / 12 / 38 / 63 / 84 min).",
        "ckf_truth.png": "Not in the paper: the CKF's errors on simulated data against its own ±3σ, a check that "
        "the Fig. 7 variances are honest.",
    },
}

#: What the quick variant (``distnav demo``) changes from the full reproduction.
QUICK_NOTES: dict[str, str] = {
    "consensus": "20,000 Monte Carlo samples instead of 100,000 (probabilities within about ±0.3 %).",
    "admm": "Fig. 5 study on 3 random problems at ρ = 0.3, 1, 3 instead of 40 at 0.3–10; ρ sweep on a 20-node "
    "network at 4 values instead of 100 nodes at 11 — counts such as 'slower in 3 of 3' are not the full "
    "run's.",
    "ckf": "40 epochs instead of 240: ratios at the last epoch are further from their limits.",
    "uwb": "1 instance per class and 60 iterations instead of 50 / 50 / 100 instances and 500 iterations: RMSE, "
    "cost and step-size numbers are far from converged and do not match the paper's setting.",
    "codebias": "120 epochs and 300 iterations instead of 300 and 1000, and no ρ-scale comparison: several "
    "'iterations to 1 mm' are not reached within the run.",
    "ckf-ionosphere": "150 one-minute epochs instead of 960: the DCB times and the after-1-h ratios cover only the "
    "first 2.5 h of the day.",
}

#: The paper's value for headline labels that do not carry a ``(paper …)`` part: (experiment, regex, value).
PAPER_VALUES: tuple[tuple[str, str, str], ...] = (
    ("consensus", r"^max \|r_i", "P1 ≈ P3 faster than P2, P4 (Fig. 3)"),
    ("admm", r"^Fig\. 5, C=\{1,3,4,6,9\}: iterations", "not printed (Fig. 5 curves)"),
    ("admm", r"^Fig\. 5, C=\{1,3,4,9\}: iterations", "never fewer than with C = {1,3,4,6,9}"),
    ("admm", r"reduced C slower than full", "in every draw ('never faster')"),
    ("admm", r"final max_i|final relative deviation|Gauss-Newton", "0 (the centralized solution)"),
    ("admm", r"method of multipliers g\(u\) increasing", "True (Fig. 3)"),
    ("admm", r"ADMM z0=.7 g\(u\) increasing", "False (Fig. 4, magenta triangles)"),
    ("admm", r"iterations to 1e-6 at best ρ", "not comparable (other network)"),
    ("admm", r"best ρ", "an interior ρ (Fig. 9; values not comparable)"),
    ("ckf", r"messages lost", "not in the paper (fault test)"),
    ("ckf", r"CKF/central std ratio", "decreasing to 1 as k_n grows"),
    ("ckf", r"local/central std ratio", "above every CKF ratio"),
    ("ckf", r"^α max", "≥ 1, decreasing to 1 (eq. 46)"),
    ("ckf", r"eq\. \(47\)", "0 (closed form)"),
    ("ckf", r"^RMS", "≈ 1 (consistent)"),
    ("ckf", r"not estimable", "not stated"),
    ("ckf-ionosphere", r"^initial", "√13 = 3.606"),
    ("ckf-ionosphere", r"after 1 h.*\(min\)", "1.5"),
    ("ckf-ionosphere", r"after 1 h.*\(max\)", "3"),
    ("ckf-ionosphere", r"k_n=12", "very close to 1"),
    ("ckf-ionosphere", r"within ±3σ", "not in the paper (a check of Fig. 7)"),
    ("ckf-ionosphere", r"k_n=4|worst receiver", "receivers 1, 3, 13 worst (value not printed)"),
    ("ckf-ionosphere", r"k_n=6", "between k_n = 4 and 12 (value not printed)"),
    ("ckf-ionosphere", r"median \[min\]", "38"),
    ("ckf-ionosphere", r"max \[min\]", "84"),
    ("codebias", r"ρ = 5$", "very slow"),
    ("codebias", r"ρ = 0\.5$", "fastest of the four"),
    ("codebias", r"ρ = 0\.05$|ρ = 0\.005$", "slower than ρ = 0.5"),
    ("codebias", r"x⁰ = prev|x⁰ = 0 / prev", "prev. fastest (Fig. 10)"),
    ("codebias", r"^σ of x̂", "well-tracked satellite more precise (Fig. 8)"),
    ("uwb", r"RMSE LM", "above 1 m (LM stagnates)"),
    ("uwb", r"RMSE N-CSG", "generally below 0.6 m"),
    ("uwb", r"median cost", "all 8 (LM lowest cost)"),
    ("uwb", r"bytes per message", "neighbourhood-sized (N-CSG) vs network-sized (CSG)"),
)


#: What a verdict of the claims table means (:mod:`distnav.experiments.claims`).
VERDICT_MEANINGS: dict[str, str] = {
    AGREE: "distnav's number meets the paper's statement, read as the row's note says",
    DIFFER: "it does not; the note says why (a departure of the paper, a synthetic stand-in, a quick run's size)",
    NOT_CHECKABLE: "no run can measure it (an illustration, unpublished data) or this run lacks the field",
}

#: What a solver's status means (``SolverResult.status``, ``distnav.algorithms.result.SolverStatus``).
STATUS_MEANINGS: dict[str, str] = {
    "converged": "the stopping rule was met",
    "max_iterations": "the iteration budget ran out first (estimates usable, not at the tolerance)",
    "stopped": "a filter ran out of epochs before every state was estimable",
    "diverged": "the iterates blew up; the estimates are not usable",
    "ambiguous": "the data admit more than one solution (e.g. a mirror image); the estimates are one of them",
    "weakly_determined": "converged, but some anchors or parameters are barely constrained (reported weak)",
}


def legend_lines() -> list[str]:
    """The report's key: each verdict and each solver status with its meaning, one ``'word: meaning'`` each."""
    return [f"{k}: {v}" for k, v in (VERDICT_MEANINGS | STATUS_MEANINGS).items()]


def _legend_html() -> str:
    def dl(title: str, d: dict[str, str]) -> str:
        items = "; ".join(f"<b>{html.escape(k)}</b>: {html.escape(v)}" for k, v in d.items())
        return f"<p><b>{title}</b> {items}.</p>"

    return dl("Verdicts:", VERDICT_MEANINGS) + dl("Solver statuses (in the tables below):", STATUS_MEANINGS)


def table_lines(results: Any) -> tuple[list[str], list[str]]:
    """From an experiment's ``table`` rows (uwb-field): the solver statuses per row, and its bytes beside the
    gather of ``models.uwb.communication.gather_cost`` (ranges to one anchor, positions back) where a row sent any.
    """
    table = results.get("table") if isinstance(results, dict) else None
    statuses, comm = [], []
    for row in table if isinstance(table, list) else []:
        if not isinstance(row, dict):
            continue
        name = " ".join(str(row[k]) for k in ("scenario", "placement", "solver") if k in row)
        if isinstance(row.get("statuses"), dict):
            counts_txt = ", ".join(f"{k} {v}" for k, v in row["statuses"].items())
            statuses.append(f"{name}: {counts_txt} (of {row.get('instances', '?')} halls)")
        sent, gather = row.get("bytes"), row.get("gather_bytes")
        if isinstance(sent, (int, float)) and isinstance(gather, (int, float)) and sent > 0 and gather > 0:
            comm.append(
                f"{name}: sent {sent / 1e3:,.1f} kB in {row.get('messages', 0):,.0f} messages per solve (mean); "
                f"gathering the ranges at one anchor and sending the positions back would cost "
                f"{gather / 1e3:,.2f} kB: {sent / gather:,.0f}× the bytes"
            )
    return statuses, comm


def paper_value(name: str, label: str) -> str:
    """The paper's value for a headline label: its ``(paper …)`` part, else :data:`PAPER_VALUES`, else
    "not stated"."""
    _, inline = split_paper_value(label)
    if inline is not None:
        return inline
    for exp, pattern, value in PAPER_VALUES:
        if exp == name and re.search(pattern, label):
            return value
    return "not stated"


_PAPER_IN_LABEL = re.compile(r"\s*\((paper[^()]*(?:\([^()]*\)[^()]*)*)\)")


def split_paper_value(label: str) -> tuple[str, str | None]:
    """``"λ P1 (paper 0.92)"`` → ``("λ P1", "0.92")``; labels without ``(paper …)`` give ``None``."""
    m = _PAPER_IN_LABEL.search(label)
    if not m:
        return label, None
    value = re.sub(r"^paper\s*[:=]?\s*", "", m.group(1)).strip()
    return (label[: m.start()] + label[m.end() :]).strip(), value or None


def caption(name: str, figure: str, module_captions: dict[str, str] | None = None) -> str:
    if module_captions and figure in module_captions:
        return module_captions[figure]
    return FIGURE_CAPTIONS.get(name, {}).get(figure, f"{figure} (no caption yet)")


def _fmt(v: Any) -> str:
    """A value for a table cell: numbers to 4 significant digits, also inside lists and dicts (a list of 16-digit
    floats made the uwb-field table unreadable), a missing value (NaN, None) as ``—``."""
    v = to_jsonable(v)
    if isinstance(v, float):
        return f"{v:.4g}"
    if v is None:
        return "—"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{k}: {_fmt(x)}" for k, x in v.items()) + "}"
    return str(v)


def _png_size(path: Path) -> tuple[int, int] | None:
    """(width, height) in pixels from a PNG header; ``None`` when the file is missing or not a PNG."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(24)
    except OSError:
        return None
    if len(head) < 24 or head[:8] != b"\x89PNG\r\n\x1a\n":
        return None
    w, h = struct.unpack(">II", head[16:24])
    return int(w), int(h)


def _figure_class(size: tuple[int, int] | None) -> str:
    """A row of panels gets the full width, another large figure half, a small one a third."""
    if size is None:
        return ""
    w, h = size
    if w >= 1.8 * h and w > 700:
        return " class='wide'"
    return " class='half'" if w > 900 else ""


_CSS = (
    "body{font-family:system-ui,sans-serif;max-width:1200px;margin:auto;padding:0 12px;line-height:1.4}"
    "table{border-collapse:collapse;margin:6px 0;font-size:13px}td,th{border:1px solid #bbb;padding:2px 6px;"
    "vertical-align:top;overflow-wrap:break-word}th{background:#f3f3f3}figure{display:inline-block;vertical-align:top;margin:6px;"
    "width:calc(33.3% - 16px)}figure.half{width:calc(50% - 16px)}"
    "figure.wide{width:calc(100% - 16px)}figure img{width:100%;max-height:400px;object-fit:contain;"
    "border:1px solid #ccc}"
    "figcaption{font-size:13px;color:#333}.caveat{background:#fff6d6;border-left:4px solid #e0b000;padding:4px 8px}"
    "table.claims td:nth-child(4){max-width:260px}table.claims td:nth-child(6){max-width:220px}"
    "table.claims td:nth-child(8){min-width:340px;color:#444;overflow-wrap:anywhere}"
    "table.claims td:nth-child(-n+3),table.claims td:nth-child(7){white-space:nowrap}"
)


def communication_lines(results: Any) -> list[str]:
    """The ``communication_vs_gather`` lines of an experiment's results (issue 27), one per run: ``'run: line'``."""
    block = results.get("communication_vs_gather") if isinstance(results, dict) else None
    if not isinstance(block, dict):
        return []
    return [f"{k}: {v['line']}" for k, v in block.items() if isinstance(v, dict) and "line" in v]


def _field_section(out_dir: Path) -> tuple[list[str], list[str]]:
    """The section for ``out_dir/field/results.json`` (written by ``distnav field demo --out DIR/field``), if any:
    its headline numbers and verdicts; nothing when the file is absent."""
    path = out_dir / "field" / "results.json"
    if not path.is_file():
        return [], []
    res = json.loads(path.read_text(encoding="utf-8"))
    title = f"Field runtime: {res.get('nodes', '?')} node processes on loopback (distnav field demo)"
    rows = [(str(k), _fmt(v)) for k, v in res.get("headline", {}).items()]
    rows += [(str(k), "ok" if v else "FAIL") for k, v in res.get("verdicts", {}).items()]
    parts = [
        f"<h2 id='field'>{html.escape(title)}</h2>",
        "<p><a href='field/results.json'>results.json</a></p>",
        "<table><tr><th>quantity</th><th>distnav</th></tr>",
    ]
    parts += [f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in rows]
    parts.append("</table>")
    md = [f"## {title}", "", "[field/results.json](field/results.json)", "", "| quantity | distnav |", "|---|---|"]
    md += [f"| {k.replace('|', chr(92) + '|')} | {v.replace('|', '/')} |" for k, v in rows]
    return parts, [*md, ""]


def _entry_section(
    out_dir: Path, name: str, title: str, figures: list[str], results: Any, seconds: float, *, quick: bool
) -> tuple[list[str], list[str]]:
    """One experiment's section (HTML lines, Markdown lines): its title and run time, the quick variant's caveat,
    the headline table beside the paper's values, the communication lines and the captioned figures."""
    import importlib

    from distnav.experiments import EXPERIMENTS

    mod_caps: dict[str, str] | None = None
    if name in EXPERIMENTS:
        mod_caps = getattr(importlib.import_module(EXPERIMENTS[name]), "FIGURE_CAPTIONS", None)
    rel = Path(name)
    parts = [
        f"<h2 id='{html.escape(name)}'>{html.escape(title)}</h2>",
        f"<p>{seconds:.1f} s &middot; <a href='{rel}/results.json'>results.json</a></p>",
    ]
    md = [f"## {title}", "", f"{seconds:.1f} s — [{rel}/results.json]({rel}/results.json)", ""]
    if quick and name in QUICK_NOTES:
        parts.append(f"<p class='caveat'>Quick variant: {html.escape(QUICK_NOTES[name])}</p>")
        md += [f"> Quick variant: {QUICK_NOTES[name]}", ""]
    headline = results.get("headline", {}) if isinstance(results, dict) else {}
    if headline:
        _headline_table(name, headline, parts, md)
    if comm_lines := communication_lines(results):
        parts.append(
            "<p><b>Communication</b> (beside gathering the same data at one node by multi-hop relaying):<br>"
            + "<br>".join(html.escape(t) for t in comm_lines)
            + "</p>"
        )
        md += ["**Communication** (beside gathering the same data at one node by multi-hop relaying):", ""]
        md += [f"- {t}" for t in comm_lines] + [""]
    statuses, table_comm = table_lines(results)
    for head, tail, lines in (
        ("Solver statuses", " (meanings under the summary)", statuses),
        ("Communication", " (per solve, beside a gather over the range graph)", table_comm),
    ):
        if lines:
            text = "<br>".join(html.escape(t) for t in lines)
            parts.append(f"<p><b>{head}</b>{html.escape(tail)}:<br>{text}</p>")
            md += [f"**{head}**{tail}:", ""] + [f"- {t}" for t in lines] + [""]
    for fig in figures:
        cap = caption(name, fig, mod_caps)
        cls = _figure_class(_png_size(out_dir / rel / fig))
        parts.append(
            f"<figure{cls}><a href='{rel}/{fig}' title='open full size'><img src='{rel}/{fig}' "
            f"alt='{html.escape(fig)}' loading='lazy'></a><figcaption>{html.escape(cap)} "
            f"<a href='{rel}/{fig}'>[full size]</a></figcaption></figure>"
        )
        md += [f"[![{fig}]({rel}/{fig})]({rel}/{fig})", "", f"*{cap}*", ""]
    md.append("")
    return parts, md


def _headline_table(name: str, headline: dict[str, Any], parts: list[str], md: list[str]) -> None:
    """The headline numbers beside the paper's values, appended to the HTML ``parts`` and the Markdown ``md``."""
    parts.append("<table><tr><th>quantity</th><th>distnav</th><th>paper</th></tr>")
    md += ["| quantity | distnav | paper |", "|---|---|---|"]
    for k, v in headline.items():
        label = split_paper_value(str(k))[0]
        paper_txt = paper_value(name, str(k))
        parts.append(
            f"<tr><td>{html.escape(label)}</td><td>{html.escape(_fmt(v))}</td><td>{html.escape(paper_txt)}</td></tr>"
        )
        md.append(f"| {label.replace('|', chr(92) + '|')} | {_fmt(v)} | {paper_txt.replace('|', '/')} |")
    parts.append("</table>")
    md.append("")


def write_report(
    out_dir: Path, entries: list[tuple[str, str, Any, dict[str, Any], float]], *, quick: bool = True
) -> Path:
    """Write ``out_dir/index.html`` and ``out_dir/REPORT.md``; returns the HTML path.

    ``entries`` are ``(name, title, context, results, seconds)``; ``context.figures`` lists the PNGs written in
    ``out_dir/name``. ``quick`` states the quick-variant caveats (``distnav demo`` runs the quick variants).
    """
    out_dir = Path(out_dir)
    rows = [r for name, _, _, results, _ in entries if isinstance(results, dict) for r in claims_for(name, results)]
    c = counts(rows)
    summary = (
        f"{len(rows)} paper claims checked by this run: <b>{c[AGREE]} agree</b>, <b>{c[DIFFER]} differ"
        f"</b>, {c[NOT_CHECKABLE]} not checkable."
    )
    variant = (
        "These are the <b>quick variants</b> of every reproduction (what changes is said under each "
        "heading), so some numbers differ from the full runs quoted in the README; "
        "<code>docs/claims.md</code> has the same table from a full run. Run <code>distnav reproduce NAME "
        "--out DIR</code> for a full one."
        if quick
        else "Full reproductions."
    )
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>distnav demo report</title>",
        f"<style>{_CSS}</style></head><body>",
        f"<h1>distnav demo report</h1><p>distnav {__version__}. Each section reproduces a figure set of one paper: "
        "000 = Khodabandeh &amp; Teunissen 2019 (ADMM, GNSS code biases), 002 = Krška &amp; Navrátil 2024 (UWB), "
        "003 = Khodabandeh, Teunissen &amp; Zaminpardaz 2017 (consensus, CKF, ionosphere).</p>",
        f"<p class='caveat'>{variant}</p>",
        f"<h2 id='summary'>Summary: what the papers claim and what distnav measured</h2><p>{summary}</p>",
        html_table(rows),
        _legend_html(),
        "<p>Contents: "
        + " · ".join(f"<a href='#{html.escape(n)}'>{html.escape(t)}</a>" for n, t, *_ in entries)
        + "</p>",
    ]
    md = [
        f"# distnav demo report (distnav {__version__})",
        "",
        re.sub(r"</?(b|code)>", "", variant).replace("&amp;", "&"),
        "",
        "## Summary: what the papers claim and what distnav measured",
        "",
        re.sub(r"</?b>", "", summary),
        "",
        markdown_table(rows),
        "",
        "What the verdicts and the solver statuses mean:",
        "",
        *[f"- {line}" for line in legend_lines()],
        "",
    ]
    for name, title, ctx, results, seconds in entries:
        entry_html, entry_md = _entry_section(out_dir, name, title, ctx.figures, results, seconds, quick=quick)
        parts += entry_html
        md += entry_md
    field_html, field_md = _field_section(out_dir)
    parts += field_html
    md += field_md
    parts.append("</body></html>")
    index = out_dir / "index.html"
    atomic_write_text(index, "\n".join(parts))
    atomic_write_text(out_dir / "REPORT.md", "\n".join(md) + "\n")
    return index

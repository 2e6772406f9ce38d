"""Bad-input audit (issue 15): every command and experiment option, and the public API, given bad input.

The target: 0 tracebacks and 0 silent wrong answers. A CLI case passes when ``distnav.cli.main`` returns or exits
with code 2, prints ``error: ...`` naming the problem (the expected text) and no traceback, and leaves no output
behind. An API case passes when the call raises a :class:`distnav.errors.DistnavError` whose message contains the
expected text (every such error is also the builtin it specialises, so ``except ValueError`` keeps working).

Cases that fail because the validation lives in another part's territory are marked ``xfail(strict=True)`` with
the owner; the mark comes off when the owner's branch lands (strict: an unexpected pass fails the suite).
The data files are small ones written here: no case needs ../shared.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from distnav import options
from distnav.cli import main
from distnav.errors import DistnavError


@dataclass(frozen=True)
class Cli:
    id: str
    argv: tuple[str, ...]
    expect: str  # text the error message must contain (case-insensitive)
    owner: str | None = None  # xfail reason when the check is another helper's


# bad values by option type: every option of demo and reproduce is covered from the parser itself
BAD_VALUES: dict[Callable[[str], Any], list[tuple[str, str]]] = {
    options.positive_int: [
        ("0", "must be at least 1"),
        ("-3", "must be at least 1"),
        ("x", "expected a whole number"),
        ("2.5", "expected a whole number"),
    ],
    options.nonnegative_int: [("-1", "must be 0 or more"), ("four", "expected a whole number")],
    options.seed: [
        ("-1", "seed must be 0 or more"),
        ("abc", "expected a whole number"),
        ("1.5", "expected a whole number"),
    ],
    options.existing_file: [("{tmp}/none.rnx", "no such file"), ("{tmp}", "not a file")],
    options.iso_datetime: [
        ("not-a-date", "expected an ISO date"),
        ("2024-13-01T00:00", "expected an ISO date"),
        ("", "expected an ISO date"),
    ],
    options.output_folder: [
        ("{file}", "is an existing file"),
        ("{file}/sub", "is a file, not a folder"),
        ("/proc/distnav-audit/x", "cannot create output folder"),
        ("", "empty path"),
    ],
}


def _subparsers(
    parser: argparse.ArgumentParser, path: tuple[str, ...] = ()
) -> Iterator[tuple[tuple[str, ...], argparse.ArgumentParser]]:
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _subparsers(sub, (*path, name))


def _options(parser: argparse.ArgumentParser) -> list[argparse.Action]:
    return [
        a
        for a in parser._actions
        if a.option_strings and not isinstance(a, (argparse._HelpAction, argparse._VersionAction))
    ]


def _bounded_bad_values(kind: object) -> list[tuple[str, str]]:
    """The bad values of a size option's type (:class:`~distnav.options.IntUpTo`): below its least, not whole,
    one above its limit."""
    if not isinstance(kind, options.IntUpTo):
        return []
    low = "must be 0 or more" if kind.minimum == 0 else f"must be at least {kind.minimum}"
    return [
        (str(kind.minimum - 1), low),
        ("x", "expected a whole number"),
        ("2.5", "expected a whole number"),
        (str(kind.maximum + 1), f"at most {kind.maximum:,}, got {kind.maximum + 1} ("),
    ]


def _derived_cases(path: tuple[str, ...], parser: argparse.ArgumentParser) -> list[Cli]:
    """Every option of ``distnav demo`` / ``reproduce NAME``: the bad values of its type, a bad choice,
    ``--ranks`` without MPI, an unknown option, and a missing required option."""
    name = "-".join(path)
    prefix = (*path, "--quick") if path[0] == "reproduce" else path
    o = ("--out", "{tmp}/out")
    cases = [Cli(f"{name}-unknown-option", (*prefix, *o, "--frobnicate"), "unrecognized arguments")]
    if any("--ranks" in a.option_strings for a in _options(parser)):  # reproduce-all has no backend options
        cases.append(Cli(f"{name}-ranks-inprocess", (*prefix, *o, "--ranks", "2"), "applies only with --backend mpi"))
    for action in _options(parser):
        flag = action.option_strings[0]
        rest = () if flag == "--out" else o
        if action.required:
            cases.append(Cli(f"{name}-{flag[2:]}-missing", prefix, f"required: {flag}"))
        if action.choices is not None:
            cases.append(Cli(f"{name}-{flag[2:]}-choice", (*prefix, *rest, flag, "bogus"), "invalid choice"))
        elif action.nargs == 0:
            cases.append(Cli(f"{name}-{flag[2:]}-value", (*prefix, *rest, f"{flag}=yes"), "ignored explicit"))
        else:
            bad = _bounded_bad_values(action.type) or BAD_VALUES.get(action.type)  # type: ignore[arg-type]
            assert bad, f"{name} {flag}: type {action.type!r} has no bad values in this audit"
            cases += [Cli(f"{name}-{flag[2:]}-{i}", (*prefix, *rest, flag, v), e) for i, (v, e) in enumerate(bad)]
    return cases


def _experiment_cases() -> list[Cli]:
    from distnav.cli import build_parser

    cases = [
        Cli("reproduce-unknown", ("reproduce", "nonsense", "--out", "{tmp}/out"), "invalid choice"),
        Cli("reproduce-none", ("reproduce",), "required"),
        Cli("demo-only-empty", ("demo", "--out", "{tmp}/out", "--only"), "expected at least one argument"),
        Cli(
            "demo-jobs-mpi",
            ("demo", "--out", "{tmp}/out", "--jobs", "2", "--backend", "mpi"),
            "--jobs 2 applies only with the in-process backend",
        ),
    ]
    for path, parser in _subparsers(build_parser()):
        if path and path[0] in {"demo", "reproduce", "reproduce-all"} and (path[0] != "reproduce" or len(path) == 2):
            cases += _derived_cases(path, parser)
    return cases


def _uwb_cases() -> list[Cli]:
    base = ("uwb", "solve", "--ranges", "{ranges}", "--known", "{known}")
    o = ("--out", "{tmp}/out")
    files = [("ranges", "--ranges"), ("known", "--known")]
    cases = [
        Cli("uwb-solve-none", ("uwb",), "required"),
        Cli("uwb-solve-no-ranges", ("uwb", "solve", "--known", "{known}", *o), "required: --ranges"),
        Cli("uwb-solve-no-out", base, "required: --out"),
        Cli("uwb-solve-out-file", (*base, "--out", "{file}"), "is an existing file"),
        Cli("uwb-solve-out-under-file", (*base, "--out", "{file}/x"), "is a file, not a folder"),
        Cli("uwb-solve-out-cannot-create", (*base, "--out", "/proc/distnav-audit/x"), "cannot create output folder"),
        Cli("uwb-solve-solver", (*base, *o, "--solver", "magic"), "invalid choice"),
        Cli("uwb-solve-loss", (*base, *o, "--loss", "square"), "invalid choice"),
        Cli("uwb-solve-ranks-zero", (*base, *o, "--ranks", "0"), "must be at least 1"),
        Cli("uwb-solve-ranks-inprocess", (*base, *o, "--ranks", "3"), "applies only with --backend mpi"),
        Cli("uwb-solve-backend", (*base, *o, "--backend", "tcp"), "invalid choice"),
        Cli("uwb-solve-iterations-text", (*base, *o, "--iterations", "ten"), "expected a whole number"),
        Cli("uwb-solve-loss-scale-text", (*base, *o, "--loss-scale-m", "wide"), "invalid float value"),
        # values only the uwb command can judge (checked before solving)
        Cli("uwb-solve-iterations-zero", (*base, *o, "--iterations", "0"), "--iterations"),
        Cli("uwb-solve-iterations-negative", (*base, *o, "--iterations", "-5"), "--iterations"),
        Cli("uwb-solve-loss-scale-zero", (*base, *o, "--loss", "huber", "--loss-scale-m", "0"), "loss"),
        Cli("uwb-solve-loss-scale-negative", (*base, *o, "--loss", "huber", "--loss-scale-m", "-1"), "loss"),
        Cli("uwb-solve-loss-scale-nan", (*base, *o, "--loss", "huber", "--loss-scale-m", "nan"), "loss"),
        Cli("uwb-solve-objective", (*base, *o, "--objective", "cubic"), "invalid choice"),
        Cli("uwb-solve-sigma-zero", (*base, *o, "--sigma-m", "0"), "--sigma-m"),
        Cli("uwb-solve-sigma-text", (*base, *o, "--sigma-m", "tight"), "invalid float value"),
        Cli("uwb-solve-no-exclude-value", (*base, *o, "--no-exclude=yes"), "ignored explicit"),
        Cli("uwb-solve-level-zero", (*base, *o, "--level", "0"), "level"),
        Cli("uwb-solve-level-one", (*base, *o, "--level", "1.5"), "level"),
        Cli("uwb-solve-range-offsets", (*base, *o, "--range-offsets", "all"), "invalid choice"),
        Cli(
            "uwb-solve-common-delays-distributed",
            (*base, *o, "--range-offsets", "common_delays", "--solver", "N-CLM"),
            "common_delays is LM's only",
        ),
        Cli("uwb-solve-estimate-prior-no-delays", (*base, *o, "--estimate-offset-prior"), "--estimate-offset-prior"),
        Cli(
            "uwb-solve-offset-prior-negative",
            (*base, *o, "--range-offsets", "per_anchor", "--offset-prior-sigma-m", "-1"),
            "offset-prior-sigma-m",
        ),
        Cli("uwb-solve-delay-sigma-negative", (*base, *o, "--delay-sigma-m", "-0.01"), "--delay-sigma-m"),
        Cli("uwb-solve-delay-sigma-nan", (*base, *o, "--delay-sigma-m", "nan"), "--delay-sigma-m"),
        Cli(
            "uwb-solve-reliability-limit-negative", (*base, *o, "--reliability-limit-m", "-1"), "--reliability-limit-m"
        ),
        Cli("uwb-solve-reliability-limit-inf", (*base, *o, "--reliability-limit-m", "inf"), "--reliability-limit-m"),
        Cli("uwb-solve-allow-planar-value", (*base, *o, "--allow-planar-3d=yes"), "ignored explicit"),
        Cli("uwb-solve-required-accuracy-zero", (*base, *o, "--required-accuracy-m", "0"), "must be greater than 0"),
        Cli("uwb-solve-required-accuracy-nan", (*base, *o, "--required-accuracy-m", "nan"), "--required-accuracy-m"),
        Cli("uwb-solve-strict-value", (*base, *o, "--strict=yes"), "ignored explicit"),
        Cli("uwb-solve-no-refine-value", (*base, *o, "--no-refine=yes"), "ignored explicit"),
        Cli("uwb-solve-no-refine-lm", (*base, *o, "--no-refine"), "--no-refine"),
        Cli("uwb-import-april-no-log", ("uwb", "import-april", *o), "required: log"),
        Cli("uwb-import-april-missing", ("uwb", "import-april", "{tmp}/none.txt", *o), "none.txt"),
        Cli("uwb-import-april-no-out", ("uwb", "import-april", "{file}"), "required: --out"),
        Cli("uwb-import-april-known", ("uwb", "import-april", "--known", "8,x", *o, "{file}"), "--known"),
        Cli("uwb-import-april-delays", ("uwb", "import-april", "--delays", "auto", *o, "{file}"), "invalid choice"),
    ]
    for key, flag in files + [("initial", "--initial"), ("truth", "--truth"), ("heights", "--heights")]:
        argv = tuple("{tmp}/missing.csv" if a == f"{{{key}}}" else a for a in base)
        if key not in dict(files):
            argv = (*base, flag, "{tmp}/missing.csv")
        cases.append(Cli(f"uwb-solve-{key}-missing", (*argv, *o), "missing.csv"))
    # malformed files: each error names the file
    for key, content, expect, owner in [
        ("ranges", "", "empty", None),
        ("ranges", "a,b\nA00,A01\n", "range_m", None),
        ("ranges", "a,b,range_m\nA00,A01,far\n", ":2", None),
        ("ranges", "a,b,range_m\nA00,A01,-3\n", ":2", None),
        ("ranges", "a,b,range_m\nA00,A00,3\n", ":2", None),
        ("ranges", "a,b,range_m\nA00,A01,nan\n", ":2", None),
        ("known", "id,x_m\nA00,1\n", "y_m", None),
        ("known", "id,x_m,y_m,z_m\nA00,1,2,zz\n", ":2", None),
        ("known", "id,x_m,y_m,z_m\nZZ9,1,2,3\n", "ZZ9", None),
        ("known", "id,x_m,y_m,z_m\nA00,1,2,3\nA00,1,2,3\n", "twice", None),
    ]:
        argv = tuple(f"{{write:{key}:{content}}}" if a == f"{{{key}}}" else a for a in base)
        cases.append(Cli(f"uwb-solve-{key}-bad-{len(cases)}", (*argv, *o), expect, owner))
    return cases


def _gnss_cases() -> list[Cli]:
    """GNSS option values are checked before the (dummy) files are read: an option error must name the option."""
    o = ("--out", "{tmp}/out")
    cb = ("gnss", "codebias", "--obs", "{obs}", "--nav", "{nav}")
    io = ("gnss", "ionosphere", "--obs", "{obs}", "{obs2}", "--nav", "{nav}")
    cases = [
        Cli("gnss-none", ("gnss",), "required"),
        Cli("gnss-codebias-no-obs", ("gnss", "codebias", "--nav", "{nav}", *o), "required: --obs"),
        Cli("gnss-codebias-nav-and-sp3", (*cb, "--sp3", "{nav}", *o), "not allowed with argument"),
        Cli("gnss-codebias-out-file", (*cb, "--out", "{file}"), "is an existing file"),
        Cli("gnss-codebias-out-under-file", (*cb, "--out", "{file}/x"), "is a file, not a folder"),
        Cli("gnss-codebias-ranks-zero", (*cb, *o, "--ranks", "0"), "must be at least 1"),
        Cli("gnss-codebias-ranks-inprocess", (*cb, *o, "--ranks", "2"), "applies only with --backend mpi"),
        Cli("gnss-codebias-weighting", (*cb, *o, "--weighting", "cos"), "invalid choice"),
        Cli("gnss-codebias-admm-messages", (*cb, *o, "--admm-messages", "float16"), "invalid choice"),
        Cli("gnss-codebias-sigma-text", (*cb, *o, "--sigma", "small"), "invalid float value"),
        Cli("gnss-codebias-obs-missing", ("gnss", "codebias", "--obs", "{tmp}/no.rnx", "--nav", "{nav}", *o), "no.rnx"),
        Cli("gnss-codebias-tlim-one", (*cb, *o, "--tlim", "2024-01-10T00:00"), "expected 2 arguments"),
        Cli("gnss-compare-no-bias", ("gnss", "compare", "--estimates", "{file}"), "required: --bias"),
        Cli(
            "gnss-compare-out-file",
            ("gnss", "compare", "--estimates", "{file}", "--bias", "{nav}", "--out", "{file}"),
            "is an existing file",
        ),
        Cli(
            "gnss-compare-estimates-missing",
            ("gnss", "compare", "--estimates", "{tmp}/none.json", "--bias", "{nav}"),
            "none.json",
        ),
        Cli("gnss-compare-estimates-not-json", ("gnss", "compare", "--estimates", "{file}", "--bias", "{nav}"), "file"),
        Cli("gnss-ionosphere-out-file", (*io, "--out", "{file}"), "is an existing file"),
        Cli("gnss-ionosphere-ranks-zero", (*io, *o, "--ranks", "0"), "must be at least 1"),
        Cli("gnss-ionosphere-ionosphere", (*io, *o, "--ionosphere", "global"), "invalid choice"),
        Cli("gnss-ionosphere-system", (*io, *o, "--system", "X"), "invalid choice"),
        Cli("gnss-ionosphere-kn-text", (*io, *o, "--kn", "x"), "invalid int value"),
    ]
    for cmd, argv in (("codebias", cb), ("ionosphere", io)):
        for opt, value in [
            ("--sigma", "0"),
            ("--sigma", "-1"),
            ("--interval", "0"),
            ("--interval", "-30"),
            ("--mask", "-5"),
            ("--mask", "95"),
            ("--nav-max-age", "0"),
            ("--tlim", "2024-01-10T02:00 2024-01-10T01:00"),
            ("--tlim", "yesterday today"),
        ]:
            if cmd == "ionosphere" and opt == "--sigma" and value == "-1":
                continue
            cases.append(Cli(f"gnss-{cmd}-{opt[2:]}-{value.split()[0]}", (*argv, *o, opt, *value.split()), opt))
    cases += [
        Cli("gnss-codebias-rho-zero", (*cb, *o, "--rho", "0"), "--rho"),
        Cli("gnss-codebias-iterations-zero", (*cb, *o, "--iterations", "0"), "--iterations"),
        Cli("gnss-codebias-codes-garbage", (*cb, *o, "--codes", "L1:C1C"), "--codes"),
        Cli("gnss-codebias-graph-missing", (*cb, *o, "--graph", "{tmp}/none.csv"), "none.csv"),
        Cli("gnss-ionosphere-kn-negative", (*io, *o, "--kn", "-1"), "--kn"),
        Cli("gnss-ionosphere-pivot-garbage", (*io, *o, "--pivot", "XYZ"), "--pivot"),
        Cli("gnss-ionosphere-datum-satellites-prn", (*io, *o, "--datum-satellites", "G01,G40"), "--datum-satellites"),
        Cli("gnss-ionosphere-datum-satellites-file", (*io, *o, "--datum-satellites", "{tmp}/no.bia"), "no.bia"),
        Cli("gnss-ionosphere-l1-code", (*io, *o, "--l1-code", "Q9"), "--l1-code"),
        Cli("gnss-ionosphere-regional-zero", (*io, *o, "--regional-km", "0"), "--regional-km"),
        Cli("gnss-ionosphere-tec-rw-zero", (*io, *o, "--tec-rw", "0"), "--tec-rw"),
        Cli("gnss-ionosphere-tec-rw-text", (*io, *o, "--tec-rw", "stiff"), "invalid float value"),
        Cli("gnss-ionosphere-min-satellite-obs-zero", (*io, *o, "--min-satellite-obs", "0"), "--min-satellite-obs"),
        Cli("gnss-ionosphere-tec-field-choice", (*io, *o, "--tec-field", "cubic"), "invalid choice"),
        Cli("gnss-ionosphere-mapping-choice", (*io, *o, "--mapping", "flat"), "invalid choice"),
        Cli("gnss-ionosphere-model-spread-choice", (*io, *o, "--model-spread", "on"), "invalid choice"),
        Cli("gnss-ionosphere-glonass-ifb-negative", (*io, *o, "--glonass-ifb-sigma-ns", "-1"), "--glonass-ifb"),
        Cli("gnss-ionosphere-innovation-test-one", (*io, *o, "--innovation-test", "1"), "--innovation-test"),
        Cli("gnss-ionosphere-innovation-test-zero", (*io, *o, "--innovation-test", "0"), "--innovation-test"),
        Cli("gnss-ionosphere-between-station-one", (*io, *o, "--between-station-level", "0.5"), "--between-station"),
        Cli("gnss-ionosphere-between-station-text", (*io, *o, "--between-station-level", "x"), "invalid float value"),
        Cli("gnss-codebias-backend", (*cb, *o, "--backend", "tcp"), "invalid choice"),
        Cli("gnss-codebias-no-progress-value", (*cb, *o, "--no-progress=yes"), "ignored explicit"),
        Cli("gnss-codebias-reference-empty", (*cb, *o, "--reference", ""), "--reference"),
        Cli("gnss-codebias-bias-missing", (*cb, *o, "--bias", "{tmp}/none.bia"), "none.bia"),
        Cli("gnss-ionosphere-backend", (*io, *o, "--backend", "tcp"), "invalid choice"),
        Cli("gnss-ionosphere-weighting", (*io, *o, "--weighting", "cos"), "invalid choice"),
        Cli("gnss-ionosphere-no-progress-value", (*io, *o, "--no-progress=yes"), "ignored explicit"),
        Cli("gnss-ionosphere-nav-and-sp3", (*io, *o, "--sp3", "{nav}"), "not allowed with argument"),
        Cli("gnss-ionosphere-graph-missing", (*io, *o, "--graph", "{tmp}/none.csv"), "none.csv"),
        Cli("gnss-ionosphere-bias-missing", (*io, *o, "--bias", "{tmp}/none.bia"), "none.bia"),
        Cli("gnss-ionosphere-l2-code", (*io, *o, "--l2-code", "Q9"), "--l2-code"),
        Cli("gnss-ionosphere-datum", (*io, *o, "--datum", "mean"), "invalid choice"),
        Cli("gnss-ionosphere-reference", (*io, *o, "--reference", "BELE00BRA"), "--reference"),
        Cli("gnss-ionosphere-exclude", (*io, *o, "--exclude", "TOOLONG"), "--exclude"),
        Cli("gnss-ionosphere-compare-exclude", (*io, *o, "--compare-exclude", "X1"), "exclude"),
        Cli(
            "gnss-ionosphere-c1-corrections-missing",
            (*io, *o, "--c1-corrections", "{tmp}/none.bia"),
            "--c1-corrections",
        ),
        Cli(
            "gnss-ionosphere-c1-corrections-c1w",
            (*io, *o, "--l1-code", "C1W", "--c1-corrections", "{file}"),
            "--c1-corrections",
        ),
        Cli("gnss-ionosphere-datum-pivot-without-pivot", (*io, *o, "--datum", "pivot"), "--datum pivot needs --pivot"),
        Cli("gnss-ionosphere-pivot-without-datum-pivot", (*io, *o, "--pivot", "G10"), "--datum pivot"),
        Cli(
            "gnss-ionosphere-tlim-other-day",
            (
                "gnss",
                "ionosphere",
                "--obs",
                "{obsday}",
                "--nav",
                "{nav}",
                *o,
                "--tlim",
                "2024-01-11T00:00",
                "2024-01-11T02:00",
            ),
            "outside the day(s) of the --obs files (2024-01-10)",
        ),
        Cli(
            "gnss-ionosphere-nav-of-one-day-for-two",
            ("gnss", "ionosphere", "--obs", "{obsday}", "{obsday2}", "--nav", "{navday}", *o),
            "no --nav file of 2024-01-11",
        ),
        Cli("gnss-ionosphere-levelling", (*io, *o, "--levelling", "smooth"), "invalid choice"),
        Cli("gnss-ionosphere-min-arc", (*io, *o, "--min-arc", "0"), "--min-arc"),
        Cli("gnss-ionosphere-gf-threshold", (*io, *o, "--gf-threshold", "0"), "--gf-threshold"),
        Cli("gnss-ionosphere-no-screening-value", (*io, *o, "--no-screening=yes"), "ignored explicit"),
        Cli("gnss-ionosphere-allow-other-day-value", (*io, *o, "--allow-other-day=yes"), "ignored explicit"),
        Cli(
            "gnss-compare-filter",
            ("gnss", "compare", "--estimates", "{file}", "--bias", "{nav}", "--filter", "best"),
            "--filter",
        ),
        Cli(
            "gnss-compare-exclude",
            ("gnss", "compare", "--estimates", "{file}", "--bias", "{nav}", "--exclude", "G99"),
            "--exclude",
        ),
        Cli(
            "gnss-compare-allow-other-day-value",
            ("gnss", "compare", "--estimates", "{file}", "--bias", "{nav}", "--allow-other-day=yes"),
            "ignored explicit",
        ),
    ]
    return cases


_NET = (
    "{write:net:version = 1\n[[node]]\nid = 0\naddress = 'tcp://127.0.0.1:5000'\nneighbours = [1]\n"
    "[[node]]\nid = 1\naddress = 'tcp://127.0.0.1:5001'\nneighbours = [0]\n}"
)


def _field_cases() -> list[Cli]:
    """``distnav node`` and ``distnav field launch|keys`` (issue 26)."""
    o = ("--out", "{tmp}/out")
    node = ("node", "--config", _NET)
    launch = ("field", "launch", "--config", _NET)
    return [
        Cli("field-none", ("field",), "required"),
        Cli("node-no-config", ("node", "--id", "0", *o), "required: --config"),
        Cli("node-config-absent", ("node", "--config", "{tmp}/none.toml", "--id", "0", *o), "no such file"),
        Cli("node-config-not-toml", ("node", "--config", "{write:bad:version = [}", "--id", "0", *o), "valid TOML"),
        Cli(
            "node-config-asymmetric",
            ("node", "--config", _NET.replace("neighbours = [0]", "neighbours = []"), "--id", "0", *o),
            "node 0 lists neighbour 1, but node 1 does not list 0",
        ),
        Cli("node-id-negative", (*node, "--id", "-1", *o), "must be 0 or more"),
        Cli("node-id-absent", (*node, "--id", "5", *o), "--id 5: the description has nodes 0..1"),
        Cli("node-id-missing", (*node, *o), "required: --id"),
        Cli("node-out-file", (*node, "--id", "0", "--out", "{file}"), "is an existing file"),
        Cli("node-rejoin-value", (*node, "--id", "0", *o, "--rejoin=yes"), "ignored explicit"),
        Cli("field-launch-no-config", ("field", "launch", *o), "required: --config"),
        Cli("field-launch-out-file", (*launch, "--out", "{file}"), "is an existing file"),
        Cli("field-launch-timeout", (*launch, *o, "--timeout", "0"), "must be"),
        Cli("field-keys-no-config", ("field", "keys", *o), "required: --config"),
        Cli("field-keys-out-file", ("field", "keys", "--config", _NET, "--out", "{file}"), "is an existing file"),
    ]


def _field_async_cases() -> list[Cli]:
    """field init, field demo and the node programs they start (issue 26 items 3, 5, 8)."""
    init = ("field", "init", "--ranges", "{ranges}")
    out = ("--out", "{tmp}/n.toml")
    demo = ("field", "demo", "--out", "{tmp}/out")
    cases = [
        Cli(
            "field-init-no-source",
            ("field", "init", *out),
            "one of the arguments --ranges --rinex --simulate is required",
        ),
        Cli("field-init-simulate-kind", ("field", "init", "--simulate", "x", *out), "invalid choice"),
        Cli("field-init-simulate-nodes", ("field", "init", "--simulate", "ckf", "--nodes", "0", *out), "at least 1"),
        Cli("field-init-simulate-hall-3", ("field", "init", "--simulate", "hall", "--nodes", "3", *out), "at least 4"),
        Cli(
            "field-init-simulate-seed",
            ("field", "init", "--simulate", "ckf", "--seed", "-1", *out),
            "seed must be 0 or more",
        ),
        Cli("field-init-both-sources", (*init, "--rinex", "{obs}", *out), "not allowed with argument"),
        Cli("field-init-ranges-missing", ("field", "init", "--ranges", "{tmp}/none.csv", *out), "no such file"),
        Cli("field-init-rinex-missing", ("field", "init", "--rinex", "{tmp}/none.rnx", *out), "no such file"),
        Cli("field-init-rinex-one", ("field", "init", "--rinex", "{obs}", *out), "at least 2 station files"),
        Cli("field-init-k-zero", (*init, "--k", "0", *out), "must be at least 1"),
        Cli("field-init-min-ranges-zero", (*init, "--min-ranges", "0", *out), "must be at least 1"),
        Cli("field-init-min-ranges-high", (*init, "--min-ranges", "2", *out), "no partner with at least 2"),
        Cli("field-init-hosts-bad", (*init, "--hosts", "a b", *out), "not a host name"),
        Cli("field-init-hosts-count", (*init, "--hosts", "h1,h2", *out), "2 hosts for 4 nodes"),
        Cli("field-init-base-port-low", (*init, "--base-port", "80", *out), "1024..65535"),
        Cli("field-init-base-port-high", (*init, "--base-port", "65534", *out), "passes port 65535"),
        Cli("field-init-name-empty", (*init, "--name", " ", *out), "non-empty printable name"),
        Cli("field-init-out-exists", (*init, "--out", "{file}"), "never overwrites"),
        Cli("field-init-out-no-folder", (*init, "--out", "{tmp}/nowhere/n.toml"), "does not exist"),
        Cli("field-demo-nodes-few", (*demo, "--nodes", "3"), "at least 4"),
        Cli("field-demo-nodes-many", (*demo, "--nodes", "65"), "at most 64"),
        Cli("field-demo-rounds-zero", (*demo, "--rounds", "0"), "must be at least 1"),
        Cli("field-demo-kill-round-zero", (*demo, "--kill-round", "0"), "must be at least 1"),
        Cli("field-demo-kill-round-late", (*demo, "--rounds", "10", "--kill-round", "10"), "--kill-round must be"),
        Cli("field-demo-pushsum-seconds", (*demo, "--pushsum-seconds", "0"), "must be greater than 0"),
        Cli("field-demo-timeout", (*demo, "--timeout", "soon"), "expected a number"),
        Cli("field-demo-seed", (*demo, "--seed", "-1"), "seed must be 0 or more"),
        Cli("field-demo-uwb-iterations", (*demo, "--uwb-iterations", "0"), "must be at least 1"),
        Cli("field-demo-deadline", (*demo, "--deadline-ms", "-5"), "must be greater than 0"),
        Cli("field-demo-out-file", ("field", "demo", "--out", "{file}"), "is an existing file"),
    ]
    for cmd in ("pushsum-node", "demo-uwb-node"):
        node = ("field", cmd, "--config", _NET, "--id", "0", "--out", "{tmp}/out")
        cases += [
            Cli(
                f"field-{cmd}-config",
                ("field", cmd, "--config", "{tmp}/none.toml", "--id", "0", "--out", "{tmp}/o"),
                "no such file",
            ),
            Cli(f"field-{cmd}-id-text", (*node[:4], "--id", "one", *node[6:]), "expected a whole number"),
            Cli(f"field-{cmd}-id-range", (*node[:4], "--id", "2", *node[6:]), "the description has nodes 0..1"),
            Cli(f"field-{cmd}-out-file", (*node[:6], "--out", "{file}"), "is an existing file"),
        ]
    node = ("field", "pushsum-node", "--config", _NET, "--id", "0", "--out", "{tmp}/out")
    uwb = ("field", "demo-uwb-node", "--config", _NET, "--id", "0", "--out", "{tmp}/out")
    return [
        *cases,
        Cli("field-pushsum-node-period", (*node, "--period-ms", "0"), "must be greater than 0"),
        Cli("field-pushsum-node-duration", (*node, "--duration-s", "long"), "expected a number"),
        Cli("field-demo-uwb-node-seed", (*uwb, "--seed", "-2"), "seed must be 0 or more"),
        Cli("field-demo-uwb-node-iterations", (*uwb, "--iterations", "0"), "must be at least 1"),
    ]


CLI_CASES = [
    Cli("no-command", (), "required"),
    Cli("unknown-command", ("fly",), "invalid choice"),
    *_experiment_cases(),
    *_uwb_cases(),
    *_gnss_cases(),
    *_field_async_cases(),
    *_field_cases(),
]

GOOD_RANGES = "a,b,range_m\nA00,A01,5.0\nA00,A02,5.0\nA01,A02,5.0\nA00,A03,5.0\nA01,A03,5.0\nA02,A03,7.07\n"
GOOD_KNOWN = "id,x_m,y_m,z_m\nA00,0,0,0\nA01,5,0,0\nA02,0,5,0\n"


def _expand(argv: tuple[str, ...], tmp: Path) -> list[str]:
    (tmp / "afile.txt").write_text("not a folder\n")
    (tmp / "ranges.csv").write_text(GOOD_RANGES)
    (tmp / "known.csv").write_text(GOOD_KNOWN)
    for name in ("obs.rnx", "obs2.rnx", "nav.rnx", "dgar0100.24o", "dgar0110.24o", "brdc0100.24n"):
        (tmp / name).write_text("dummy\n")
    subs = {
        "{tmp}": str(tmp),
        "{file}": str(tmp / "afile.txt"),
        "{ranges}": str(tmp / "ranges.csv"),
        "{known}": str(tmp / "known.csv"),
        "{obs}": str(tmp / "obs.rnx"),
        "{obs2}": str(tmp / "obs2.rnx"),
        "{nav}": str(tmp / "nav.rnx"),
        "{obsday}": str(tmp / "dgar0100.24o"),
        "{obsday2}": str(tmp / "dgar0110.24o"),
        "{navday}": str(tmp / "brdc0100.24n"),
    }
    out = []
    for a in argv:
        if a.startswith("{write:"):
            key, content = a[len("{write:") : -1].split(":", 1)
            path = tmp / f"bad_{key}.csv"
            path.write_text(content)
            out.append(str(path))
            continue
        for k, v in subs.items():
            a = a.replace(k, v)
        out.append(a)
    return out


def _marks(owner: str | None) -> list[Any]:
    return [pytest.mark.xfail(strict=True, reason=owner)] if owner else []


def _outputs(tmp: Path) -> list[Path]:
    out = tmp / "out"
    return sorted(out.rglob("*")) if out.exists() else []


@pytest.mark.parametrize("case", [pytest.param(c, id=c.id, marks=_marks(c.owner)) for c in CLI_CASES])
def test_cli_bad_input(
    case: Cli, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    argv = _expand(case.argv, tmp_path)
    monkeypatch.chdir(tmp_path)  # commands with a default --out write here
    try:
        code = main(argv)
    except SystemExit as exc:  # argparse: bad option values end the parse
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2, f"exit code {code!r}; stderr: {err[-600:]}"
    assert "Traceback" not in err
    assert "error:" in err
    assert case.expect.lower() in err.lower(), err[-600:]
    assert not _outputs(tmp_path), "output written although the input was refused"


def test_mpi_backend_without_the_extra(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The hint names the distribution's extra (not ``pip install mpi4py.MPI``), before any work."""
    monkeypatch.setitem(sys.modules, "mpi4py", None)  # import mpi4py → ImportError
    monkeypatch.setitem(sys.modules, "mpi4py.MPI", None)
    for argv in (
        ["reproduce", "consensus", "--quick", "--out", str(tmp_path / "out"), "--backend", "mpi"],
        ["demo", "--out", str(tmp_path / "out"), "--backend", "mpi", "--ranks", "2"],
        [
            "uwb",
            "solve",
            *_expand(("--ranges", "{ranges}", "--known", "{known}"), tmp_path),
            "--out",
            str(tmp_path / "out"),
            "--backend",
            "mpi",
        ],
    ):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert "pip install 'mpi4py>=4.0' 'mpich>=4.1'" in err and "pip install '.[mpi]'" in err
        assert "distnav-estimation[" not in err  # not on the package index: a hint that cannot work
        assert not (tmp_path / "out").exists()


def test_out_folder_not_left_behind(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """A run refused after the folder check leaves no (empty) output folder: the probe removes what it made."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / "obs.rnx").write_text("dummy\n")
    code = main(["gnss", "codebias", "--obs", "obs.rnx", "--nav", "obs.rnx", "--out", "deep/er/out"])
    assert code == 2 and "error:" in capsys.readouterr().err
    assert not (tmp_path / "deep").exists()
    assert not (tmp_path / "distnav-codebias").exists()


# ------------------------------------------------------------------------------------------------- API
@dataclass(frozen=True)
class Api:
    id: str
    call: Callable[[], Any]
    expect: str
    owner: str | None = None


def _api_cases() -> list[Api]:
    from distnav._optional import require
    from distnav.algorithms import statistics
    from distnav.algorithms.consensus.averaging import average_consensus, consensus_product
    from distnav.algorithms.lsq.blue import LinearProblem, blue
    from distnav.exchange import FaultSchedule, make_exchange
    from distnav.experiments import load
    from distnav.experiments.common import ExperimentContext
    from distnav.network import Graph, builders, consensus_weights

    ring = builders.ring(5)
    ctx = lambda **o: ExperimentContext(out_dir=Path("unused"), options=o)  # noqa: E731
    good = LinearProblem.from_blocks([np.eye(2)] * 5, [np.zeros(2)] * 5)
    cases = [
        Api("ctx-epochs-zero", lambda: ctx(epochs=0).option("epochs", 120, minimum=1), "--epochs must be at least 1"),
        Api("ctx-instances-negative", lambda: ctx(instances=-1).option("instances", None, minimum=1), "--instances"),
        Api("ctx-data-kn-negative", lambda: ctx(data_kn=-1).option("data_kn", 4, minimum=0), "--data-kn"),
        Api("check-out-file", lambda: options.check_output_folder(__file__), "is an existing file"),
        Api("check-out-empty", lambda: options.check_output_folder(""), "empty path"),
        Api("probe-out-proc", lambda: options.probe_output_folder("/proc/distnav-audit/x"), "cannot create"),
        Api(
            "require-missing",
            lambda: require("distnav_no_such_module", "plot"),
            "pip install 'matplotlib>=3.8' (the plot extra; in a distnav clone: pip install '.[plot]')",
        ),
        Api("load-unknown-experiment", lambda: load("nonsense"), "unknown experiment"),
        Api("ring-too-small", lambda: builders.ring(1), "ring"),
        Api("graph-bad-link", lambda: Graph.from_links(3, [(0, 5)]), "5"),
        Api("graph-self-link", lambda: Graph.from_links(3, [(1, 1)]), "1"),
        Api("weights-unknown", lambda: consensus_weights(ring, "P9"), "P9"),
        Api("exchange-backend", lambda: make_exchange(ring, backend="carrier-pigeon"), "carrier-pigeon"),
        Api("faults-probability", lambda: FaultSchedule(drop_probability=1.5), "drop"),
        Api("consensus-rounds-negative", lambda: average_consensus(np.ones(5), graph=ring, rounds=-1), "rounds"),
        Api("consensus-values-shape", lambda: average_consensus(np.ones(4), graph=ring, rounds=3), "5"),
        Api("consensus-nan", lambda: average_consensus(np.full(5, np.nan), graph=ring, rounds=3), "finite"),
        Api("consensus-product-rounds", lambda: consensus_product(consensus_weights(ring, "P3"), -2), "rounds"),
        Api("lsq-shapes", lambda: LinearProblem.from_blocks([np.eye(2)], [np.zeros(3)]), "node 0"),
        Api("lsq-R-not-pd", lambda: LinearProblem.from_blocks([np.eye(2)], [np.zeros(2)], [-np.eye(2)]), "node 0"),
        Api(
            "blue-rank-deficient", lambda: blue(LinearProblem.from_blocks([np.ones((2, 2))], [np.ones(2)])), "estimable"
        ),
        Api("stat-level", lambda: statistics.critical_value(1.5), "level"),
        Api("stat-w-shapes", lambda: statistics.w_statistics(np.ones(3), np.ones(2)), "shape"),
        Api("stat-vf-negative", lambda: statistics.variance_factor(-1.0, 3), "weighted residual"),
    ]
    from distnav.algorithms.lsq.admm import admm

    cases += [
        Api("admm-graph-size", lambda: admm(good, builders.ring(4)), "4"),
        Api("admm-W-negative", lambda: admm(good, ring, W=-1.0), "W"),
        Api("admm-iterations-zero", lambda: admm(good, ring, max_iterations=0), "max_iterations=0"),
    ]
    from distnav.experiments.uwb import instance_problem
    from distnav.formats.uwb.io import read_positions, read_ranges

    cases.append(
        Api(
            "uwb-reproduce-start", lambda: instance_problem("GC", np.random.default_rng(0), start="vertical"), "--start"
        )
    )

    cases += [
        Api("uwb-read-ranges-missing", lambda: read_ranges("/nonexistent/r.csv"), "r.csv"),
        Api("uwb-read-positions-missing", lambda: read_positions("/nonexistent/p.csv"), "p.csv"),
    ]
    return cases


def _api_params() -> list[Any]:
    return [pytest.param(c, id=c.id, marks=_marks(c.owner)) for c in _api_cases()]


@pytest.mark.parametrize("case", _api_params())
def test_api_bad_input(case: Api) -> None:
    with pytest.raises(DistnavError) as info:
        case.call()
    assert case.expect.lower() in str(info.value).lower(), str(info.value)


def _command_path(argv: tuple[str, ...]) -> tuple[str, ...]:
    path = []
    for a in argv:
        if a.startswith("-"):
            break
        path.append(a)
    return tuple(path)


def test_every_option_has_a_case() -> None:
    """Every option of every command and experiment appears in at least one bad-input case."""
    from distnav.cli import build_parser

    used = {(_command_path(c.argv), a.split("=")[0]) for c in CLI_CASES for a in c.argv if a.startswith("--")}
    missing = [
        f"{' '.join(path)} {action.option_strings[0]}"
        for path, parser in _subparsers(build_parser())
        if path and not any(isinstance(a, argparse._SubParsersAction) for a in parser._actions)
        for action in _options(parser)
        if not any((path, f) in used for f in action.option_strings)
    ]
    assert not missing, missing


def test_enough_cases() -> None:
    """Issue 15's target: at least 150 bad-input cases through the CLI and the API."""
    assert len(CLI_CASES) + len(_api_cases()) + 1 >= 150
    assert len({c.id for c in CLI_CASES}) == len(CLI_CASES)

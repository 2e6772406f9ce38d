"""``distnav field demo``: the three runs on node processes, their numbers against independent references, checked
options (nothing started on a bad one), clean-up on Ctrl-C, and its section in the demo report."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from distnav.cli import main

pytest.importorskip("zmq")
pytest.importorskip("tomli_w")


def test_demo_on_four_processes(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "field"
    rc = main(
        [
            "field",
            "demo",
            "--nodes",
            "4",
            "--rounds",
            "120",
            "--kill-round",
            "15",
            "--pushsum-seconds",
            "4",
            "--uwb-iterations",
            "10",
            "--deadline-ms",  # the killed runs wait 3 deadlines to notice the loss (and the UWB agreement a window
            "2000",  # of deadlines): 2 s as the other field loss tests, not the demo's generous 5 s (82 -> ~50 s)
            "--timeout",
            "200",
            "--out",
            str(out),
        ]
    )
    printed = capsys.readouterr().out
    res = json.loads((out / "results.json").read_text())
    assert rc == 0, (printed, res["verdicts"], res["failed"])
    assert res["max_abs_diff_vs_inprocess"] == 0.0  # bitwise
    victim = res["killed_node"]
    assert res["lost_nodes"] == [victim] and res["false_losses"] == []
    # recompute the references from the nodes' own data files (independent of the demo's arithmetic)
    data = np.array([np.loadtxt(out / "consensus_killed" / "data" / f"node-{i}.txt") for i in range(4)])
    keep = np.arange(4) != victim
    killed = res["runs"]["consensus_killed"]
    est = np.array(
        [json.loads((out / "consensus_killed" / f"node-{i}.json").read_text())["estimate"] for i in killed["finished"]]
    )
    assert killed["finished"] == [i for i in range(4) if i != victim]
    assert np.abs(est - data[keep].mean(axis=0)).max() <= 1e-6
    ps = [json.loads((out / "pushsum_async" / f"node-{i}.json").read_text()) for i in range(4)]
    assert np.abs(np.array([r["estimate"] for r in ps]) - data.mean(axis=0)).max() <= 1e-6
    assert ps[0]["ticks"] < 0.6 * min(r["ticks"] for r in ps[1:])  # node 0 ticks 3x slower
    assert res["uwb_max_abs_diff_vs_inprocess_m"] == 0.0  # N-CSG-TBLS on node processes: bitwise
    assert res["runs"]["uwb_clean"]["finished"] == [0, 1, 2, 3]
    uwb_killed, victim_u = res["runs"]["uwb_killed"], res["uwb_killed_node"]  # 6 anchors: 4 known, 2 free
    assert uwb_killed["anchors"] == 6 and res["uwb_killed_lost_nodes"] == [victim_u]
    assert uwb_killed["finished"] == [i for i in range(6) if i != victim_u]
    assert uwb_killed["statuses"] == ["converged_without_lost_nodes"]
    assert res["uwb_killed_max_abs_diff_vs_central_of_remaining_m"] <= 1e-3  # LM of the remaining data
    assert res["wire_bytes"] == sum(r["wire_bytes"] for r in res["runs"].values()) > 0
    for name, run in res["runs"].items():  # each run beside gathering its data at one node (issue 26 item 5)
        cmp = res["vs_gather"][name]
        assert cmp["distributed"]["bytes"] == run["wire_bytes"] and cmp["ratio_bytes"] > 1
        assert cmp["line"] in printed
    assert "consensus, 1 killed" in printed and "FAIL" not in printed
    # the demo report picks the section up
    from distnav.experiments.report import write_report

    write_report(tmp_path, [])
    report = (tmp_path / "REPORT.md").read_text()
    assert "Field runtime: 4 node processes" in report and "bitwise equal to in-process | ok" in report


@pytest.mark.parametrize(
    ("args", "match"),
    [
        (["--nodes", "3"], "at least 4"),
        (["--nodes", "65"], "at most 64"),
        (["--rounds", "20", "--kill-round", "20"], "--kill-round must be in 1..19"),
    ],
)
def test_bad_options_start_nothing(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], match: str
) -> None:
    assert main(["field", "demo", *args, "--out", str(tmp_path / "d")]) == 2
    assert match in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def test_bad_option_type_is_refused_when_parsed(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        main(["field", "demo", "--pushsum-seconds", "0", "--out", str(tmp_path / "d")])
    assert exc.value.code == 2 and "--pushsum-seconds" in capsys.readouterr().err
    assert not (tmp_path / "d").exists()


def _processes_mentioning(text: str) -> list[int]:
    found = []
    for d in Path("/proc").iterdir():
        if d.name.isdigit():
            try:
                if text in (d / "cmdline").read_bytes().decode(errors="replace"):
                    found.append(int(d.name))
            except OSError:
                continue
    return found


@pytest.mark.skipif(sys.platform != "linux", reason="reads /proc")
def test_ctrl_c_stops_every_node(tmp_path: Path) -> None:
    out = tmp_path / "ctrlc-demo"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(p for p in sys.path if p)}
    demo = subprocess.Popen(
        [sys.executable, "-m", "distnav", "field", "demo", "--nodes", "4", "--out", str(out)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
    )
    try:
        end = time.monotonic() + 120
        while time.monotonic() < end and not (out / "consensus_clean" / "node-3.stderr").exists():
            time.sleep(0.2)
        assert (out / "consensus_clean" / "node-3.stderr").exists(), "the demo never started its nodes"
        assert len(_processes_mentioning(str(out))) >= 4
        demo.send_signal(signal.SIGINT)
        _, err = demo.communicate(timeout=60)
    finally:
        if demo.poll() is None:
            demo.kill()
            demo.wait()
    assert demo.returncode == 130, err.decode()[-2000:]
    assert "interrupted" in err.decode()
    assert _processes_mentioning(str(out)) == []
    assert not (out / "results.json").exists()

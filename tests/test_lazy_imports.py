"""Start-up of an MPI job (issue 17): the modules an MPI run imports do not import scipy (nor networkx or
matplotlib) until they are used, and the deferred module behaves as the real one once used."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from distnav._optional import LazyModule, lazy

SRC = Path(__file__).resolve().parents[1] / "src"
_HEAVY = ("scipy", "networkx", "matplotlib", "georinex")


def _modules_after(code: str) -> list[str]:
    script = (
        f"import sys\n{code}\nimport json\n"
        f"print(json.dumps(sorted(m for m in sys.modules if m.split('.')[0] in {_HEAVY!r})))"
    )
    proc = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        timeout=120,
        env={"PYTHONPATH": str(SRC), "PATH": ""},
        stdin=subprocess.DEVNULL,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    loaded: list[str] = json.loads(proc.stdout.strip().splitlines()[-1])
    return loaded


@pytest.mark.parametrize(
    "code",
    [
        "from distnav.exchange.mpi import MPIExchange\n"
        "from distnav.algorithms.consensus.averaging import average_consensus\n"
        "from distnav.algorithms.lsq.admm import admm",
        "import distnav.cli",
    ],
)
def test_mpi_path_imports_no_scipy_networkx_or_matplotlib(code: str) -> None:
    assert _modules_after(code) == []


def test_mpi_path_imports_no_logging_pathlib_or_nonlinear_admm() -> None:
    """Start-up work the MPI path never needs: logging (only the exact cover's time-limit warning logs), pathlib
    (partition files) and the nonlinear ADMM variants (re-exported from distnav.algorithms.lsq.admm on first use)."""
    code = (
        "import sys\nfrom distnav.exchange.mpi import MPIExchange\n"
        "from distnav.algorithms.consensus.averaging import average_consensus\n"
        "from distnav.algorithms.lsq.admm import admm\n"
        "print(sorted(m for m in ('logging', 'pathlib', 'distnav.algorithms.lsq.nonlinear')\n"
        "             if m in sys.modules))\n"
        "from distnav.algorithms.lsq.admm import admm_nonlinear, gauss_newton\n"
        "print(admm_nonlinear.__module__, gauss_newton.__module__)"
    )
    proc = subprocess.run(
        [sys.executable, "-c", code],
        capture_output=True,
        text=True,
        timeout=120,
        env={"PYTHONPATH": str(SRC), "PATH": ""},
        stdin=subprocess.DEVNULL,
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.splitlines() == ["[]", "distnav.algorithms.lsq.nonlinear distnav.algorithms.lsq.nonlinear"]


def test_first_use_imports_scipy_sparse_and_runs() -> None:
    code = (
        "import numpy as np\nfrom distnav.algorithms.lsq.admm import admm\nfrom distnav.algorithms.lsq.blue import "
        "LinearProblem\nfrom distnav.network.graph import Graph\n"
        "g = Graph.from_links(4, [(0, 1), (1, 2), (2, 3)])\n"
        "A = np.ones((4, 1, 1)); r = admm(LinearProblem.from_stacked(A, np.arange(4.0)[:, None]), g, "
        "max_iterations=300, tol=1e-12)\nassert abs(r.estimates[0, 0] - 1.5) < 1e-8, r.estimates"
    )
    assert "scipy.sparse" in _modules_after(code)


def test_lazy_module_resolves_on_first_attribute() -> None:
    mod = lazy("json.decoder")
    assert isinstance(mod, LazyModule)
    assert "JSONDecoder" not in vars(mod)
    assert mod.JSONDecoder is sys.modules["json.decoder"].JSONDecoder
    assert "JSONDecoder" in vars(mod)  # copied in: later reads are plain attribute reads
    with pytest.raises(AttributeError):
        _ = mod.no_such_name
    with pytest.raises(AttributeError):
        _ = lazy("json").__wrapped__  # introspection of a dunder does not import


def test_one_shared_lazy_scipy_sparse_for_every_layer() -> None:
    """``distnav._optional.scipy_sparse`` is the one deferred scipy.sparse the network, exchange and ADMM modules
    bind as ``sp``; once used it is the real module's namespace."""
    import scipy.sparse

    from distnav._optional import scipy_sparse
    from distnav.algorithms.lsq import kernel
    from distnav.exchange import mixer
    from distnav.network import constraint_nodes, graph, weights

    assert isinstance(scipy_sparse, LazyModule)
    assert all(m.sp is scipy_sparse for m in (graph, weights, constraint_nodes, mixer, kernel))
    assert scipy_sparse.csr_matrix is scipy.sparse.csr_matrix

"""Issue 29 item 3: distnav installs as a real package. The wheel and sdist are built (``python -m build``), pass
``twine check``, and the wheel installed (not editable) in a fresh venv runs a ``distnav demo --quick``-size job
from outside the source tree, importing distnav from the venv and not from ``src/``.

The fresh venv sees the dev environment's numpy/scipy/matplotlib through a ``.pth`` line (the dev environment is
itself a venv, so ``--system-site-packages`` would show the base interpreter's packages, not these), so nothing is
downloaded; ``pip install --no-index`` then proves the wheel's dependencies are satisfied without the index. The
build runs without isolation (``--no-isolation``: setuptools, ``build`` and ``twine`` come with the ``dev`` extra)
so it needs no network either.
"""

from __future__ import annotations

import os
import subprocess
import sys
import sysconfig
import tarfile
import zipfile
from pathlib import Path

import pytest

from conftest import REPO
from distnav import __version__


def _run(cmd: list[str], cwd: Path, env: dict[str, str] | None = None, timeout: float = 600) -> str:
    proc = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert proc.returncode == 0, (
        f"{' '.join(cmd)} failed ({proc.returncode}):\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    )
    return proc.stdout


@pytest.fixture(scope="module")
def dist(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("dist")
    src_copy = tmp_path_factory.mktemp("src")  # build from a copy: no build/ or egg-info left in the checkout
    _run(["git", "-C", str(REPO), "archive", "--format=tar", "-o", str(src_copy / "src.tar"), "HEAD"], REPO)
    with tarfile.open(src_copy / "src.tar") as tar:
        tar.extractall(src_copy / "tree", filter="data")
    for changed in _run(["git", "-C", str(REPO), "ls-files", "-m", "-o", "--exclude-standard"], REPO).split():
        target = src_copy / "tree" / changed  # uncommitted work counts too (the test runs on the working tree)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_bytes((REPO / changed).read_bytes())
    _run([sys.executable, "-m", "build", "--no-isolation", "--outdir", str(out), str(src_copy / "tree")], src_copy)
    return out


def _wheel(dist: Path) -> Path:
    """The one wheel built: platform-specific when the optional fault-round kernel compiled (setup.py), else pure."""
    wheels = sorted(dist.glob(f"distnav_estimation-{__version__}-*.whl"))
    assert len(wheels) == 1, sorted(p.name for p in dist.iterdir())
    return wheels[0]


def test_build_and_twine_check(dist: Path) -> None:
    wheel = _wheel(dist)
    sdist = dist / f"distnav_estimation-{__version__}.tar.gz"
    assert wheel.is_file() and sdist.is_file(), sorted(p.name for p in dist.iterdir())
    assert "PASSED" in _run([sys.executable, "-m", "twine", "check", str(wheel), str(sdist)], dist)
    names = zipfile.ZipFile(wheel).namelist()
    assert "distnav/py.typed" in names and "distnav/cli.py" in names
    assert not [n for n in names if n.startswith(("tests/", "benchmarks/"))]
    kernels = [n for n in names if n.startswith("distnav/_dropround_c")]
    # a platform wheel carries the compiled kernel, a pure one does not (the compile failed: the numpy path)
    assert bool(kernels) == (not wheel.name.endswith("-py3-none-any.whl")), (wheel.name, kernels)
    with tarfile.open(sdist) as tar:
        members = {m.name.split("/", 1)[1] for m in tar.getmembers() if "/" in m.name}
    assert {"README.md", "CHANGELOG.md", "docs/DEVELOPING.md", "pyproject.toml", "setup.py"} <= members
    assert "src/distnav/_dropround.c" in members


def test_wheel_in_a_fresh_venv_runs_a_quick_job(dist: Path, tmp_path: Path) -> None:
    venv = tmp_path / "venv"
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], tmp_path)
    python = venv / "bin" / "python"
    site = Path(_run([str(python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"], tmp_path).strip())
    (site / "dev_packages.pth").write_text(sysconfig.get_path("purelib") + "\n")  # numpy, scipy, matplotlib, pip
    wheel = _wheel(dist)
    env = {k: v for k, v in os.environ.items() if k not in {"PYTHONPATH", "PYTHONHOME"}}
    _run([str(python), "-m", "pip", "install", "--no-index", "--no-compile", f"{wheel}[plot]"], tmp_path, env)
    where = _run([str(python), "-c", "import distnav; print(distnav.__file__)"], tmp_path, env).strip()
    assert Path(where).is_relative_to(site), f"distnav imported from {where}, not from the venv's wheel"
    kernel = "from distnav import _dropround; print(_dropround.library() is not None)"
    loaded = _run([str(python), "-c", kernel], tmp_path, env).strip()
    assert loaded == str(not wheel.name.endswith("-py3-none-any.whl")), (wheel.name, loaded)  # the wheel's kernel loads
    exe = venv / "bin" / "distnav"
    assert _run([str(exe), "--version"], tmp_path, env).strip() == f"distnav {__version__}"
    _run([str(exe), "demo", "--only", "consensus", "--no-progress", "--out", "demo"], tmp_path, env)
    assert (tmp_path / "demo" / "index.html").is_file() and (tmp_path / "demo" / "consensus" / "results.json").is_file()

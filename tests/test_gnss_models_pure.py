"""Issue 25 item 5 for GNSS: the models read and write no files (formats/gnss does), and import no format."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

MODELS = Path(__file__).resolve().parents[1] / "src" / "distnav" / "models" / "gnss"
FILE_CALLS = {"write_text", "write_bytes", "read_text", "read_bytes", "mkdir", "unlink", "open"}
"""Path methods that touch files (``replace``/``rename`` are left out: ``str.replace`` and ``dataclasses.replace``
look the same), and the builtin ``open``."""
FILE_MODULES = {"gzip", "zipfile", "csv", "json"}


def _file_calls(path: Path) -> list[str]:
    found = []
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Call):
            f = node.func
            if (isinstance(f, ast.Attribute) and f.attr in FILE_CALLS) or (isinstance(f, ast.Name) and f.id == "open"):
                found.append(f"{path.name}:{node.lineno} {f.attr if isinstance(f, ast.Attribute) else 'open'}()")
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("distnav.formats"):
            found.append(f"{path.name}:{node.lineno} imports {node.module}")
        elif (isinstance(node, ast.ImportFrom) and node.module in FILE_MODULES) or (
            isinstance(node, ast.Import) and any(a.name in FILE_MODULES for a in node.names)
        ):
            found.append(f"{path.name}:{node.lineno} imports a file module")
    return found


@pytest.mark.parametrize("path", sorted(MODELS.glob("*.py")), ids=lambda p: p.name)
def test_gnss_models_touch_no_files(path: Path) -> None:
    assert _file_calls(path) == []


def test_the_check_finds_file_access(tmp_path: Path) -> None:
    f = tmp_path / "m.py"
    f.write_text(
        "import gzip\nfrom distnav.formats.gnss.rinex import read_sp3\n\n\ndef g(p, o):\n"
        "    p.write_text('x')\n    open(p)\n    return o.replace(a=1)\n",
        encoding="utf-8",
    )
    assert _file_calls(f) == [
        "m.py:1 imports a file module",
        "m.py:2 imports distnav.formats.gnss.rinex",
        "m.py:6 write_text()",
        "m.py:7 open()",
    ]

"""The layers of ARCHITECTURE.md / docs/DEVELOPING.md, checked on every import statement under src/distnav.

network → exchange → algorithms → models → formats → experiments | commands → cli: a module may import its own
layer and the layers below it, never a layer above or beside (experiments and commands do not import each other).
The utilities (errors, _optional, _sparse, _dropround, _checks, _settings, typing) sit below everything;
``output`` (file writing, figures) and ``options`` (checked CLI option types) are for experiments, commands and
the CLI only.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "distnav"

RANK = {
    "errors": 0,
    "_optional": 0.5,
    "_sparse": 0.5,
    "_dropround": 0.5,
    "_blas": 0.5,
    "_threads": 0.5,
    "_checks": 0.5,
    "_settings": 0.5,
    "typing": 0.5,
    "network": 1,
    "exchange": 2,
    "algorithms": 3,
    "models": 4,
    "output": 4.5,
    "options": 4.5,
    "formats": 4.7,
    "experiments": 5,
    "commands": 5,
    "cli": 6,
    "__main__": 7,
    "__init__": 7,
}
# ``import distnav`` / ``from distnav import __version__``: the package root only re-exports distnav.errors


def _violations(path: Path, own: str) -> list[str]:
    bad = []
    for line, module in _imports(path):
        target = _layer(module)
        if target == own or module == "distnav":
            continue
        if RANK[target] >= RANK[own]:
            bad.append(f"{path.name}:{line} imports {module} ({own} may not import {target})")
    return bad


def _layer(module: str) -> str:
    """``distnav.algorithms.kalman`` → ``algorithms``; ``distnav`` → ``__init__``."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else "__init__"


def _imports(path: Path) -> list[tuple[int, str]]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [(node.lineno, a.name) for a in node.names if a.name.startswith("distnav")]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and node.module.startswith("distnav"):
            found.append((node.lineno, node.module))
    return found


FILES = sorted(SRC.rglob("*.py"))


def test_every_layer_is_ranked() -> None:
    layers = {_layer("distnav." + ".".join(p.relative_to(SRC).with_suffix("").parts)) for p in FILES}
    assert layers <= set(RANK), layers - set(RANK)


@pytest.mark.parametrize("path", FILES, ids=lambda p: str(p.relative_to(SRC)))
def test_imports_point_downwards(path: Path) -> None:
    own = _layer("distnav." + ".".join(path.relative_to(SRC).with_suffix("").parts))
    bad = _violations(path, own)
    assert not bad, "\n".join(bad)


def test_the_check_catches_upward_and_sideways_imports(tmp_path: Path) -> None:
    """The checker itself: lazy imports inside functions count; up and sideways are refused, down is allowed."""
    f = tmp_path / "x.py"
    f.write_text(
        "import numpy\nfrom distnav.network.graph import Graph\n\n\ndef g():\n"
        "    from distnav.experiments.common import atomic_write_json\n",
        encoding="utf-8",
    )
    assert _imports(f) == [(2, "distnav.network.graph"), (6, "distnav.experiments.common")]
    assert _violations(f, "algorithms") == [
        "x.py:6 imports distnav.experiments.common (algorithms may not import experiments)"
    ]
    assert _violations(f, "commands") == [
        "x.py:6 imports distnav.experiments.common (commands may not import experiments)"
    ]
    assert _violations(f, "cli") == []
    assert _violations(f, "network") == [
        "x.py:6 imports distnav.experiments.common (network may not import experiments)"
    ]


# ------------------------------------------------------------------------------------------------ import circles
def _module_name(path: Path) -> str:
    parts = list(path.relative_to(SRC.parent).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


MODULES = {_module_name(p): p for p in FILES}


def _edges(path: Path) -> set[str]:
    """The modules of ``src/distnav`` that ``path`` imports, lazy and ``TYPE_CHECKING`` imports included:
    ``from pkg import sub`` is an edge to the submodule ``pkg.sub``, ``from pkg import Name`` to ``pkg``."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found |= {a.name for a in node.names if a.name in MODULES}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0 and node.module in MODULES:
            subs = {f"{node.module}.{a.name}" for a in node.names} & MODULES.keys()
            found |= subs or {node.module}
            if len(subs) < len(node.names):
                found.add(node.module)
    return found - {_module_name(path)}


def _circles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components of more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_circles() -> None:
    """No two modules of the house import each other, directly or through others (lazy imports count)."""
    graph = {name: _edges(path) for name, path in MODULES.items()}
    assert _circles(graph) == []


def test_the_circle_check_finds_a_circle() -> None:
    assert _circles({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == [["a", "b", "c"]]
    assert _circles({"a": {"b"}, "b": set()}) == []


# ------------------------------------------------------------------------------------------- no file writing below
WRITER_CALLS = {
    "write_text",
    "write_bytes",
    "save",
    "savez",
    "savez_compressed",
    "savetxt",
    "savefig",
    "to_csv",
    "dump",
    "atomic_write_text",
    "atomic_write_json",
    "atomic_write_bytes",
    "mkdir",
    "unlink",
    "rename",
    "replace",
    "rmtree",
}
PURE_LAYERS = ("network", "exchange", "algorithms", "models")


def _file_writes(path: Path) -> list[str]:
    """Calls under ``path`` that write, move or delete files: the writer methods above, ``open`` with a w/a/x/+
    mode. ``str.replace`` has the name of ``Path.replace``: a call with two string-like arguments is a string's."""
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = node.func.attr if isinstance(node.func, ast.Attribute) else getattr(node.func, "id", "")
        if name == "open":
            mode = (
                node.args[1] if len(node.args) > 1 else next((k.value for k in node.keywords if k.arg == "mode"), None)
            )
            if isinstance(mode, ast.Constant) and isinstance(mode.value, str) and set(mode.value) & set("wax+"):
                found.append(f"{path.name}:{node.lineno} open(..., {mode.value!r})")
        elif name in WRITER_CALLS:
            if name == "replace" and not (
                isinstance(node.func, ast.Attribute) and len(node.args) == 1 and not node.keywords
            ):
                continue  # str.replace(old, new), dataclasses.replace(obj, field=...): not Path.replace(target)
            if name == "dump" and not (
                isinstance(node.func, ast.Attribute) and getattr(node.func.value, "id", "") in ("json", "pickle", "np")
            ):
                continue
            if name == "save" and not (
                isinstance(node.func, ast.Attribute) and getattr(node.func.value, "id", "") == "np"
            ):
                continue
            found.append(f"{path.name}:{node.lineno} {name}(...)")
    return found


@pytest.mark.parametrize(
    "path", [p for p in FILES if _layer(_module_name(p)) in PURE_LAYERS], ids=lambda p: str(p.relative_to(SRC))
)
def test_layers_below_formats_write_no_files(path: Path) -> None:
    """Models (and everything below them) are pure: file writers live in ``distnav.formats`` (or return text for
    ``distnav.output``), and only formats, experiments, commands and the CLI touch the file system."""
    assert _file_writes(path) == []


def test_the_file_write_check_catches_writers(tmp_path: Path) -> None:
    f = tmp_path / "m.py"
    f.write_text(
        "import json\nimport numpy as np\n\n\ndef w(p, a, s):\n    p.write_text(s)\n"
        "    np.save(p, a)\n    open(p, 'w')\n    json.dump(a, p)\n    s.replace('a', 'b')\n"
        "    open(p)\n",
        encoding="utf-8",
    )
    assert _file_writes(f) == [
        "m.py:6 write_text(...)",
        "m.py:7 save(...)",
        "m.py:8 open(..., 'w')",
        "m.py:9 dump(...)",
    ]

"""Publishable metadata: the distribution name of our own, install lines that use it, py.typed, and an sdist that
carries every file the README links to (checked against MANIFEST.in; `python -m build --sdist` builds it)."""

from __future__ import annotations

import fnmatch
import re
import tomllib

from conftest import REPO
from distnav._optional import DISTRIBUTION, EXTRAS, install_hint

DOCS = [REPO / "README.md", REPO / "CHANGELOG.md", *sorted((REPO / "docs").glob("*.md"))]


def _pyproject() -> dict:
    return tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))


def test_distribution_name_and_metadata() -> None:
    project = _pyproject()["project"]
    assert project["name"] == DISTRIBUTION == "distnav-estimation"
    assert project["scripts"] == {"distnav": "distnav.cli:main"}  # the command stays short
    assert "Typing :: Typed" in project["classifiers"]
    assert all(dep.startswith(DISTRIBUTION + "[") for dep in project["optional-dependencies"]["dev"][:1])
    assert _pyproject()["tool"]["setuptools"]["package-data"]["distnav"] == ["py.typed"]
    assert (REPO / "src" / "distnav" / "py.typed").is_file()


def test_install_hint_names_commands_that_work() -> None:
    """distnav is not on the package index: the hint names the extra's packages (which are) and the clone's
    command; the packages are exactly pyproject's extra."""
    extras = _pyproject()["project"]["optional-dependencies"]
    assert {k: tuple(v) for k, v in extras.items() if k != "dev"} == EXTRAS
    assert (
        install_hint("mpi")
        == "pip install 'mpi4py>=4.0' 'mpich>=4.1' (the mpi extra; in a distnav clone: pip install '.[mpi]')"
    )
    for extra in EXTRAS:
        assert DISTRIBUTION not in install_hint(extra)


def test_every_install_line_works_without_the_package_index() -> None:
    """``pip install distnav`` / ``'distnav[mpi]'`` would install the index's unrelated ``distnav``, and
    ``distnav-estimation`` is not published: every install line installs from the clone (``.``, ``-e .``) or a
    wheel (``dist/...whl``), or names packages that are on the index."""
    wrong = re.compile(r"pip install\s+(?:-\S+\s+)*['\"]?distnav(?:-estimation)?(?:\[|['\"\s]|$)")
    bad = [
        f"{path.name}:{number}: {line.strip()}"
        for path in DOCS
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1)
        if wrong.search(line) and "is not on the package index" not in line
    ]
    assert not bad, bad
    assert wrong.search("pip install 'distnav[mpi]'") and wrong.search("pip install distnav")
    assert wrong.search("pip install 'distnav-estimation[mpi]'")
    assert not wrong.search("pip install '.[mpi]'")
    readme = (REPO / "README.md").read_text(encoding="utf-8")
    assert "pip install '.[mpi]'" in readme and "python -m build" in readme


def _manifest_patterns() -> list[str]:
    patterns = []
    for line in (REPO / "MANIFEST.in").read_text(encoding="utf-8").splitlines():
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        if words[0] == "include":
            patterns += words[1:]
        elif words[0] == "recursive-include":
            patterns += [f"{words[1]}/**/{p}" for p in words[2:]] + [f"{words[1]}/{p}" for p in words[2:]]
    return patterns


def test_sdist_carries_what_the_readme_links_to() -> None:
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", (REPO / "README.md").read_text(encoding="utf-8"))
    local = [link for link in links if not re.match(r"[a-z]+://", link)]
    assert local, "the README links to no local file?"
    patterns = _manifest_patterns()
    for link in local:
        assert (REPO / link).exists(), f"README links to {link}, which does not exist"
        if (REPO / link).is_file():
            assert any(fnmatch.fnmatch(link, p) for p in patterns), f"{link} is not in the sdist (MANIFEST.in)"
    for must in ("CHANGELOG.md", "LICENSE", "docs/DEVELOPING.md"):
        assert any(fnmatch.fnmatch(must, p) for p in patterns), must


def test_version_has_one_source() -> None:
    import distnav

    assert _pyproject()["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "distnav.__version__"}
    assert re.fullmatch(r"\d+\.\d+\.\d+", distnav.__version__)
    assert f"[{distnav.__version__}]" in (REPO / "CHANGELOG.md").read_text(encoding="utf-8")

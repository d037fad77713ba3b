"""The layout the next engineer relies on (docs/architecture.md): which way imports go (the
import-linter contracts in pyproject.toml), no module imported in a cycle, and packages small
enough to take in at a glance, each saying what it holds."""

from __future__ import annotations

import ast
import logging
from pathlib import Path

import grimp
import numpy as np
import pytest
from importlinter.cli import lint_imports
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tests.utils.paths import REPO

PACKAGES = ("app", "worker", "bench")
MAX_ENTRIES = 10


def test_imports_keep_to_the_layers(monkeypatch):
    monkeypatch.chdir(REPO)  # lint-imports reads pyproject.toml from the working directory
    # lint-imports configures logging with dictConfig, which disables every logger that exists:
    # the tests run after it in this process (caplog on app.*) would see no records.
    loggers = [lg for lg in logging.Logger.manager.loggerDict.values()
               if isinstance(lg, logging.Logger)]
    disabled = [lg.disabled for lg in loggers]
    try:
        assert lint_imports(no_cache=True, no_logo=True) == 0, "see the broken contract above"
    finally:
        for lg, was in zip(loggers, disabled):
            lg.disabled = was


def test_no_module_is_imported_in_a_cycle(monkeypatch):
    monkeypatch.syspath_prepend(str(REPO))
    graph = grimp.build_graph(*PACKAGES, exclude_type_checking_imports=True, cache_dir=None)
    modules = sorted(graph.modules)
    index = {m: i for i, m in enumerate(modules)}
    edges = [(index[m], index[d]) for m in modules
             for d in graph.find_modules_directly_imported_by(m) if d in index]
    rows, cols = np.array(edges).T
    n, label = connected_components(coo_matrix((np.ones(len(edges)), (rows, cols)),
                                               shape=(len(modules),) * 2), connection="strong")
    cycles = [[modules[i] for i in np.flatnonzero(label == c)] for c in range(n)]
    assert [c for c in cycles if len(c) > 1] == []


def ignored_folders() -> set[Path]:
    """The folders .gitignore names by their path (``bench/cache/``, where the benches and their
    tests keep rendered journeys): generated, not code, so neither held nor counted as entries."""
    lines = [line.strip() for line in (REPO / ".gitignore").read_text().splitlines()]
    return {Path(line.strip("/")) for line in lines
            if line.endswith("/") and "/" in line.strip("/") and "*" not in line}


IGNORED = ignored_folders()


def held_folders() -> list[Path]:
    """Every folder the size rule holds, found by walking the tree so that a new one is held too.

    Under app/, worker/ and bench/ that is every package (a folder with ``__init__.py``) and every
    folder holding Python files (one without ``__init__.py`` would be a namespace package, most
    likely a forgotten ``__init__.py``); folders of assets, not code, are exempt
    (app/service/admin/static and templates, bench/results). migrations/ is Alembic's script folder
    (``versions/`` of revisions, not a package), held only if it becomes a package. Under tests/
    every folder is a test folder and must be a package. ``__pycache__`` and hidden folders are
    never held, nor counted as entries; nor are the folders .gitignore names by path
    (``ignored_folders``).
    """
    held = []
    for top in (*PACKAGES, "migrations", "tests"):
        for folder in [REPO / top, *sorted(p for p in (REPO / top).rglob("*") if p.is_dir())]:
            rel = folder.relative_to(REPO)
            if any(part == "__pycache__" or part.startswith(".") for part in rel.parts) or any(
                    rel == ignored or ignored in rel.parents for ignored in IGNORED):
                continue
            package = (folder / "__init__.py").exists()
            code = top in PACKAGES and any(folder.glob("*.py"))
            if package or code or top == "tests":
                held.append(folder.relative_to(REPO))
    return held


@pytest.mark.parametrize("folder", held_folders(), ids=str)
def test_a_package_has_at_most_ten_entries_and_says_what_it_holds(folder):
    entries = sorted(p.name for p in (REPO / folder).iterdir()
                     if p.name != "__pycache__" and p.relative_to(REPO) not in IGNORED)
    assert len(entries) <= MAX_ENTRIES, f"{folder}: {len(entries)} entries, group them {entries}"
    init = REPO / folder / "__init__.py"
    assert init.exists(), f"{folder} is not a package (no __init__.py)"
    docstring = ast.get_docstring(ast.parse(init.read_text()))
    assert docstring and len(docstring.splitlines()) >= 2, (
        f"{init}: no docstring of two lines or more saying what the package holds")

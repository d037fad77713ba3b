"""The layout the next engineer relies on (docs/architecture.md): which way imports go (the
import-linter contracts in pyproject.toml), no module imported in a cycle, and packages small
enough to take in at a glance."""

from __future__ import annotations

import ast

import grimp
import numpy as np
import pytest
from importlinter.cli import lint_imports
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from tests.utils.paths import REPO

PACKAGES = ("app", "worker", "bench")


def test_imports_keep_to_the_layers(monkeypatch):
    monkeypatch.chdir(REPO)  # lint-imports reads pyproject.toml from the working directory
    assert lint_imports(no_cache=True, no_logo=True) == 0, "see the broken contract printed above"


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


@pytest.mark.parametrize("package", ["app/pipeline", "app/service"])
def test_a_package_has_about_ten_entries_and_each_subpackage_says_what_it_holds(package):
    top = REPO / package
    entries = [p for p in top.iterdir() if p.name != "__pycache__"]
    assert len(entries) <= 10, sorted(p.name for p in entries)
    for init in top.rglob("__init__.py"):
        if init.parent != top and "__pycache__" not in init.parts:
            docstring = ast.get_docstring(ast.parse(init.read_text()))
            assert docstring and len(docstring.splitlines()) >= 2, f"{init}: no docstring"

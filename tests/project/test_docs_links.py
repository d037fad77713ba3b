"""The docs point at files of this repository, not at one machine's paths (issue 13: docs/service.md
opened with `/work/shared/journey-format.md`), and their relative links resolve."""

from __future__ import annotations

import re

import pytest

from tests.utils.paths import REPO

DOCS = [REPO / "README.md", REPO / "CHANGELOG.md", *sorted((REPO / "docs").rglob("*.md"))]


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_no_absolute_paths_of_one_machine(doc):
    text = doc.read_text()
    assert not re.findall(r"(?<![\w.])/(?:work|home|root|Users|mnt)/[\w./-]+", text)


@pytest.mark.parametrize("doc", DOCS, ids=lambda p: str(p.relative_to(REPO)))
def test_relative_links_resolve(doc):
    for target in re.findall(r"\]\((?!https?:|#|mailto:)([^)#\s]+)", doc.read_text()):
        assert (doc.parent / target).exists(), f"{doc.name}: {target}"

"""The service's import rules (issue 14): nothing under app/service imports the Celery worker or the
command layer, not even lazily inside a function; those two are composed above it."""

import ast
from pathlib import Path

SERVICE = Path(__file__).resolve().parents[1] / "app" / "service"


def _imported_modules(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_the_service_never_imports_the_worker_or_the_commands():
    offending = {str(path.relative_to(SERVICE)): sorted(
                     m for m in _imported_modules(path)
                     if m.split(".")[0] == "worker" or m.startswith("app.commands"))
                 for path in SERVICE.rglob("*.py")}
    assert {k: v for k, v in offending.items() if v} == {}

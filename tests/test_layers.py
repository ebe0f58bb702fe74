"""The layers of the design (DESIGN.md, "Layers"): planner < envs < workers < service, each
package importing only the ones below it. Every import statement counts, at any depth: inside
functions, ``try`` blocks and ``if TYPE_CHECKING:`` blocks too."""

from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

LAYERS = ("planner", "envs", "workers", "service")
"""Bottom to top."""


def imported_modules(tree: ast.Module, package: tuple[str, ...]) -> list[tuple[int, str]]:
    """``(line, absolute module name)`` of every import in ``tree``, the module of
    ``package`` (its package path: relative imports resolve against it)."""
    found: list[tuple[int, str]] = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.extend((node.lineno, alias.name) for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level == 0:
                base = node.module or ""
            else:
                parent = package[: len(package) - (node.level - 1)]
                base = ".".join([*parent, *([node.module] if node.module else [])])
            if node.module is None:  # ``from . import a, b``: the names are modules
                found.extend((node.lineno, f"{base}.{alias.name}") for alias in node.names)
            else:
                found.append((node.lineno, base))
    return found


def upward_imports(root: Path) -> list[str]:
    """``file:line: layer imports module`` for each import of a layer above its own."""
    problems = []
    for rank, layer in enumerate(LAYERS):
        for path in sorted((root / layer).rglob("*.py")):
            relative = path.relative_to(root)
            parts = relative.with_suffix("").parts
            package = parts[:-1]  # of a module and of an ``__init__`` alike
            tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
            for line, module in imported_modules(tree, package):
                top = module.split(".", 1)[0]
                if top in LAYERS and LAYERS.index(top) > rank:
                    problems.append(f"{relative}:{line}: {layer} imports {module} ({top})")
    return problems


def test_no_layer_imports_a_layer_above_it() -> None:
    problems = upward_imports(REPO)
    assert not problems, "upward imports (planner < envs < workers < service):\n" + "\n".join(
        problems
    )


def test_every_import_form_is_seen(tmp_path: Path) -> None:
    """The checker itself: imports in functions, TYPE_CHECKING blocks and relative ones."""
    for layer in LAYERS:
        (tmp_path / layer).mkdir()
        (tmp_path / layer / "__init__.py").write_text("")
    (tmp_path / "planner" / "a.py").write_text(
        "from typing import TYPE_CHECKING\n"
        "import numpy\n"
        "if TYPE_CHECKING:\n"
        "    from service.db import Database\n"
        "def f() -> None:\n"
        "    import envs.nav_env as env\n"
    )
    (tmp_path / "envs" / "sub").mkdir()
    (tmp_path / "envs" / "sub" / "b.py").write_text(
        "from .. import robots\nfrom ...workers import mission\nfrom ..c import d\n"
    )
    (tmp_path / "service" / "c.py").write_text("import planner, envs, workers\n")
    assert upward_imports(tmp_path) == [
        "planner/a.py:4: planner imports service.db (service)",
        "planner/a.py:6: planner imports envs.nav_env (envs)",
        "envs/sub/b.py:2: envs imports workers (workers)",
    ]

"""The layout shows the method, and imports go one way: ``calib`` ← ``supportnet`` ← ``train``,
``export``. Walks every import statement (lazy ones inside functions too) with ``ast``."""

from __future__ import annotations

import ast
from collections import Counter
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("calib", "supportnet", "train", "export")
ALLOWED = {
    "calib": {"calib"},
    "supportnet": {"calib", "supportnet"},
    "train": {"calib", "supportnet", "train", "export"},
    "export": {"calib", "supportnet", "export"},
}
"""Which top-level packages each package may import (``train`` makes the shipped models, so it
exports them; ``export`` never imports ``train``)."""


def modules() -> dict[str, Path]:
    found = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            found[name] = path
    return found


def imports_of(path: Path, name: str) -> set[str]:
    """Every project module ``path`` imports, at any depth of its code."""
    out = set()
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            out |= {alias.name for alias in node.names}
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = package.split(".")
                base = ".".join(parts[: len(parts) - node.level + 1] + [base]).strip(".")
            out.add(base)
            out |= {f"{base}.{alias.name}" for alias in node.names}
    return {m for m in out if m.split(".")[0] in PACKAGES}


def graph() -> dict[str, set[str]]:
    known = modules()
    return {
        name: {m for m in imports_of(path, name) if m in known and m != name} for name, path in known.items()
    }


def test_imports_point_one_way():
    wrong = [
        f"{source} imports {target}"
        for source, targets in graph().items()
        for target in targets
        if target.split(".")[0] not in ALLOWED[source.split(".")[0]]
    ]
    assert not wrong, "imports against calib ← supportnet ← train, export:\n" + "\n".join(wrong)


def test_tests_mirror_the_arrows():
    """``tests/calib`` tests the method alone (no ``supportnet`` import), and so on up."""
    wrong = []
    for package in PACKAGES:
        for path in sorted((ROOT / "tests" / package).rglob("*.py")):
            for target in imports_of(path, "tests.x"):
                if target.split(".")[0] not in ALLOWED[package]:
                    wrong.append(f"{path.relative_to(ROOT)} imports {target}")
    assert not wrong, "\n".join(wrong)


def test_no_import_cycles():
    edges = graph()
    state: dict[str, int] = {}
    cycles = []

    def visit(node: str, trail: list[str]) -> None:
        state[node] = 1
        for nxt in sorted(edges[node]):
            if state.get(nxt) == 1:
                cycles.append(" → ".join([*trail[trail.index(nxt) :], nxt]))
            elif nxt not in state:
                visit(nxt, [*trail, nxt])
        state[node] = 2

    for node in sorted(edges):
        if node not in state:
            visit(node, [node])
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def test_module_names_are_unique():
    names = Counter(p.stem for p in modules().values() if p.name != "__init__.py")
    assert not [n for n, c in names.items() if c > 1], names


def test_one_sub_package_per_stage():
    for stage in ("init", "match", "support", "refine"):
        assert (ROOT / "calib" / stage / "__init__.py").is_file(), stage
    assert (ROOT / "calib" / "pipeline.py").is_file()
    for part in ("nets", "runtime", "cli", "report"):
        assert (ROOT / "supportnet" / part / "__init__.py").is_file(), part


def test_the_import_walker_sees_a_wrong_arrow(tmp_path):
    """Known answer: a lazy import of ``supportnet`` inside a ``calib`` function is found."""
    path = tmp_path / "bad.py"
    path.write_text("def f():\n    from supportnet.cli.app import main\n    import train.fit\n")
    assert imports_of(path, "calib.bad") >= {"supportnet.cli.app", "train.fit"}

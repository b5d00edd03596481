"""docs/design.md §4: a lower layer never imports a higher one."""

import ast
from pathlib import Path

import tpo

RANK = {"errors": 0, "atomic": 0, "lazy": 0, "locking": 0, "schema": 0, "sensing": 0,
        "deploy": 0, "graph": 1, "tabular": 2,
        "envs": 3, "algo": 4, "experiments": 5, "cli": 6}
ROOT = Path(tpo.__file__).parent


def imported_layers(path: Path) -> set[str]:
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        names = []
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module:
            names = [node.module]
        found |= {n.split(".")[1] for n in names if n.startswith("tpo.")}
    return found


def test_every_module_belongs_to_a_known_layer():
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT)
        if rel.parts == ("__init__.py",):
            continue
        assert rel.parts[0].removesuffix(".py") in RANK, f"{rel} is in no layer"


def test_no_layer_imports_a_higher_one():
    for path in ROOT.rglob("*.py"):
        rel = path.relative_to(ROOT)
        if rel.parts == ("__init__.py",):
            continue
        own = rel.parts[0].removesuffix(".py")
        for other in imported_layers(path):
            assert RANK[other] <= RANK[own], f"{rel} ({own}) imports tpo.{other}"


def test_lazy_package_names_are_exported_and_load():
    import tpo.algo
    import tpo.envs
    import tpo.experiments

    for package in (tpo.algo, tpo.envs, tpo.experiments):
        assert set(package._LAZY) <= set(package.__all__) <= set(dir(package))
        for name in package._LAZY:
            assert getattr(package, name).__name__ == name

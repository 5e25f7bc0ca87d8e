"""The import direction of the layout: a module imports only from its own layer or lower ones.

Layers, bottom to top (a repo module's layer is decided by its path):

1. ``data/*.py`` (keypoint metadata, bone tables, frame containers, config checks), ``data/formats/``
   (file readers and writers), ``data/geometry/`` (cameras, rigs, calibration files, rig check, DLT);
2. ``data/datasets/`` (multi-view datasets), ``data/synthetic/`` (scene generator), ``data/pose2d/``
   (2D training data);
3. the stages: ``models/`` (2D network, PAF grouping), ``reconstruction/`` (matching, solver, pipeline),
   ``tracking/``;
4. ``evaluation/`` (metrics, protocols, pictures);
5. entry points and tools: ``eval.py``, ``train.py``, ``stream.py``, ``benchmarks/``, ``run_folders.py``;
6. ``export/`` (motion files out of poses3d.json): it may import the layers below, nothing imports it.

Every import is walked with ``ast``, those inside functions included; only imports under
``if TYPE_CHECKING:`` (annotations, never executed) are skipped. Tests may import anything.
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("data", "models", "reconstruction", "tracking", "evaluation", "benchmarks", "export")
# (module prefix, layer); the longest matching prefix wins
LAYERS = (
    ("data", 1),
    ("data.formats", 1),
    ("data.geometry", 1),
    ("data.datasets", 2),
    ("data.synthetic", 2),
    ("data.pose2d", 2),
    ("models", 3),
    ("reconstruction", 3),
    ("tracking", 3),
    ("evaluation", 4),
    ("eval", 5),
    ("train", 5),
    ("run_folders", 5),
    ("stream", 5),
    ("benchmarks", 5),
    ("export", 6),
)


def layer_of(module: str) -> int | None:
    """The layer of a repo module ('data.formats.poses_io'), None for anything outside the repo."""
    best = None
    for prefix, layer in LAYERS:
        if module == prefix or module.startswith(prefix + "."):
            if best is None or len(prefix) > len(best[0]):
                best = (prefix, layer)
    return None if best is None else best[1]


def module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def repo_modules() -> list[Path]:
    files = [ROOT / "eval.py", ROOT / "train.py", ROOT / "run_folders.py", ROOT / "stream.py"]
    for package in PACKAGES:
        files += sorted((ROOT / package).rglob("*.py"))
    return [f for f in files if f.exists()]


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    """ids of the nodes inside ``if TYPE_CHECKING:`` blocks."""
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If):
            test = node.test
            name = test.id if isinstance(test, ast.Name) else test.attr if isinstance(test, ast.Attribute) else None
            if name == "TYPE_CHECKING":
                for child in node.body:
                    skip.update(id(n) for n in ast.walk(child))
    return skip


def imports_of(path: Path) -> list[tuple[int, str]]:
    """(line, imported module) of every import in the file, relative imports resolved."""
    tree = ast.parse(path.read_text(), filename=str(path))
    skip = _type_checking_nodes(tree)
    own = module_name(path).split(".")
    package = own if path.name == "__init__.py" else own[:-1]
    found = []
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            found += [(node.lineno, alias.name) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[: len(package) - (node.level - 1)]
                module = ".".join(base + ([node.module] if node.module else []))
            else:
                module = node.module or ""
            found.append((node.lineno, module))
            # "from pkg import submodule" imports the submodule too
            found += [
                (node.lineno, f"{module}.{alias.name}")
                for alias in node.names
                if (ROOT / Path(*module.split("."), alias.name)).with_suffix(".py").exists()
                or (ROOT / Path(*module.split("."), alias.name, "__init__.py")).exists()
            ]
    return found


def upward_imports() -> list[str]:
    bad = []
    for path in repo_modules():
        own = layer_of(module_name(path))
        for line, module in imports_of(path):
            layer = layer_of(module)
            if own is not None and layer is not None and layer > own:
                bad.append(f"{path.relative_to(ROOT)}:{line}: layer {own} imports {module} (layer {layer})")
    return bad


def test_layer_of_paths() -> None:
    assert layer_of("data.keypoints") == 1 and layer_of("data.formats.poses_io") == 1
    assert layer_of("data.datasets.shelf") == 2 and layer_of("data.pose2d") == 2
    assert layer_of("reconstruction.solver.map_solver") == 3 and layer_of("evaluation.protocols.shelf") == 4
    assert layer_of("eval") == 5 and layer_of("evaluator") is None and layer_of("numpy") is None
    assert layer_of("export.bvh") == 6 and layer_of("exporter") is None


def test_walker_sees_imports_inside_functions(tmp_path) -> None:
    assert len(repo_modules()) > 50
    calls = [m for p in repo_modules() for _, m in imports_of(p)]
    assert any(m.startswith("data.") for m in calls)


def test_no_module_imports_a_higher_layer() -> None:
    bad = upward_imports()
    assert not bad, "imports from a higher layer:\n" + "\n".join(bad)

"""The project's shape: imports run one way, nbvdata never imports torch, pytest runs quietly."""

import ast
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("nbvdata", "nbvtrain")
# The one import against the flow, by design: `nbvdata generate --policy` loads the torch side of
# the policy seam (issue 17) inside nbvdata.policy.load_policy, only when a policy is given.
SEAM = ("nbvdata.policy", "nbvtrain.policy")


def _imports(path: Path) -> set[str]:
    """Every module a file imports, at the top or inside a function, by full name."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.add(node.module)
            # `from nbvdata import shards` imports the module nbvdata.shards
            found.update(f"{node.module}.{alias.name}" for alias in node.names
                         if (ROOT / node.module.replace(".", "/") / f"{alias.name}.py").exists())
    return found


def _graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (packages' own __init__ left out)."""
    modules = {f"{p}.{f.stem}": f for p in PACKAGES for f in (ROOT / p).glob("*.py") if f.stem != "__init__"}
    graph = {name: _imports(path) & modules.keys() for name, path in modules.items()}
    graph[SEAM[0]].discard(SEAM[1])
    return graph


def _module_level_imports(path: Path) -> set[str]:
    """The modules a file imports at its top level (run by any import of it)."""
    tree = ast.parse(path.read_text())
    top = ast.Module(body=[node for node in tree.body if isinstance(node, (ast.Import, ast.ImportFrom))],
                     type_ignores=[])
    found = set()
    for node in ast.walk(top):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.add(node.module)
    return found


def test_imports_run_one_way():
    graph = _graph()
    cycles = []
    for start in graph:
        stack, seen = [(start, [start])], set()
        while stack:
            module, trail = stack.pop()
            for dep in graph[module]:
                if dep == start:
                    cycles.append(" -> ".join(trail + [dep]))
                elif dep not in seen:
                    seen.add(dep)
                    stack.append((dep, trail + [dep]))
    assert not cycles, f"import cycles: {cycles}"


def test_nbvdata_never_imports_torch_or_nbvtrain():
    for path in (ROOT / "nbvdata").glob("*.py"):
        bad = {name for name in _imports(path) if name.split(".")[0] in ("torch", "nbvtrain")}
        if path.stem == SEAM[0].split(".")[1]:
            assert SEAM[1] not in _module_level_imports(path), "the policy seam must import nbvtrain lazily"
            bad.discard(SEAM[1])
        assert not bad, f"{path.name} imports {bad}"


def test_pytest_runs_without_the_dash_plugin_warning():
    """open3d pulls in dash, whose pytest plugin warned on every run (pyproject: -p no:dash)."""
    result = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "tests/test_render.py"],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Warning" not in result.stdout + result.stderr

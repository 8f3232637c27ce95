"""The project's shape: imports run one way (nbvtrain -> nbvdata, never back), nbvdata never
imports torch, pytest runs quietly."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("nbvdata", "nbvtrain")


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
    return {name: _imports(path) & modules.keys() for name, path in modules.items()}


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
    """Not at the top, not inside a function, not by a module name handed to importlib: the policy
    seam goes through the nbvdata.policies entry points (pyproject.toml), which nbvtrain registers."""
    for path in (ROOT / "nbvdata").glob("*.py"):
        bad = {name for name in _imports(path) if name.split(".")[0] in ("torch", "nbvtrain")}
        named = {node.value for node in ast.walk(ast.parse(path.read_text()))
                 if isinstance(node, ast.Constant) and isinstance(node.value, str)
                 and re.fullmatch(r"(torch|nbvtrain)(\.\w+)*(:\w+)?", node.value)}
        assert not bad and not named, f"{path.name} imports {bad or named}"


def test_nbvtrain_registers_its_policy_provider():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    points = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["nbvdata.policies"]
    assert points == {"checkpoint": "nbvtrain.policy:CheckpointPolicy"}
    module, name = points["checkpoint"].split(":")
    assert re.search(rf"^class {name}\b", (ROOT / (module.replace(".", "/") + ".py")).read_text(), re.M)


def test_pytest_runs_without_the_dash_plugin_warning():
    """open3d pulls in dash, whose pytest plugin warned on every run (pyproject: -p no:dash)."""
    result = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "tests/test_render.py"],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Warning" not in result.stdout + result.stderr

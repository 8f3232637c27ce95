"""The project's shape: every module in one stage of the one-way flow (``STAGES``, the table
docs/design.md states), importing only its own stage and earlier ones; nbvtrain's learning
modules read nbvdata only through its schema side; nbvdata never imports torch; no private name
crosses into nbvtrain, the benchmarks, the recipes or the examples; benchmarks/ holds measurements
and recipes/ the one-off recipe, each script cited; pytest runs quietly."""

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


# The stages in the order data flows: settings and words; the shard schema (what generate writes
# and training reads); the simulation (mesh -> views -> sensor -> grid -> coverage -> oracle ->
# scene -> episode); the dataset jobs and tools; learning on shards; planning and closed loop.
STAGES = (
    ("base", "nbvdata", ("text", "errors", "config", "files", "logodds", "commandline", "userarrays", "layout_scvp",
                         "layout_tammes", "views", "paths", "cloud")),
    ("schema", "nbvdata", ("shards", "summary", "manifest")),
    ("simulation", "nbvdata", ("_open3d", "mesh", "shapes", "sensor", "grid", "viewfeatures", "coverage", "oracle",
                               "setcover", "scene", "episode", "policy", "sources")),
    ("datasets", "nbvdata", ("claims", "generate", "rerun", "env", "card", "publish", "export", "gridstats", "authors",
                             "render", "cli", "__main__")),
    ("learning", "nbvtrain", ("models", "scores", "metrics", "trained_scene", "scene", "config", "training_data", "data",
                              "dataset", "checkpoint", "train", "baselines", "predict", "rl")),
    ("planning", "nbvtrain", ("_lightgbm", "trees", "rankdata", "viewrank", "surfaceprior", "rankfit", "covermodel", "covernet", "release",
                              "sensordata", "planners", "plan", "evaluate", "statistics", "benchmark", "benchmark_report", "policy", "cli",
                              "__main__")),
)
STAGE = {f"{package}.{module}": number for number, (_, package, modules) in enumerate(STAGES) for module in modules}
SCHEMA_SIDE = {name for name, stage in STAGE.items() if stage <= 1}  # what learning may read of nbvdata


def _stage_violations(graph: dict[str, set[str]]) -> list[str]:
    """"a -> b" for every import of a later stage, and of nbvdata beyond its schema side by a
    learning module."""
    bad = []
    for module, deps in sorted(graph.items()):
        for dep in sorted(deps):
            if STAGE[dep] > STAGE[module]:
                bad.append(f"{module} ({STAGES[STAGE[module]][0]}) -> {dep} ({STAGES[STAGE[dep]][0]})")
            elif STAGES[STAGE[module]][0] == "learning" and dep.startswith("nbvdata.") and dep not in SCHEMA_SIDE:
                bad.append(f"{module} (learning) -> {dep}, not the schema side")
    return bad


def test_every_module_has_its_stage():
    modules = {f"{p}.{f.stem}" for p in PACKAGES for f in (ROOT / p).glob("*.py") if f.stem != "__init__"}
    assert modules == set(STAGE), f"no row in STAGES: {sorted(modules - set(STAGE))}; gone: {sorted(set(STAGE) - modules)}"


def test_imports_flow_one_way_through_the_stages():
    """Top-level and function-level imports alike (``_imports``)."""
    assert _stage_violations(_graph()) == []


def test_a_reversed_import_is_caught():
    """The check itself: the shard schema importing the job, or a learning module the simulator, fails."""
    graph = _graph()
    graph["nbvdata.shards"] = graph["nbvdata.shards"] | {"nbvdata.generate"}
    graph["nbvtrain.training_data"] = graph["nbvtrain.training_data"] | {"nbvdata.grid"}
    assert _stage_violations(graph) == ["nbvdata.shards (schema) -> nbvdata.generate (datasets)",
                                        "nbvtrain.training_data (learning) -> nbvdata.grid, not the schema side"]


def test_the_design_page_states_the_same_stages():
    page = (ROOT / "docs" / "design.md").read_text()
    for name, package, modules in STAGES:
        row = next((line for line in page.splitlines() if line.startswith(f"| {name} |")), None)
        assert row is not None, f"docs/design.md has no row for the stage {name}"
        assert all(f"`{module}`" in row for module in modules if not module.startswith("_")), (name, row)


def test_reading_shards_loads_no_simulator():
    """``import nbvtrain.dataset`` (a torch Dataset over HDF5 files) loads neither open3d, trimesh nor
    numba, nor any simulation module."""
    code = ("import sys, nbvtrain.dataset\n"
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('open3d', 'trimesh', 'numba', 'nbvdata', 'nbvtrain'))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert not {name for name in loaded if name.split(".")[0] in ("open3d", "trimesh", "numba")}, loaded
    assert {name for name in loaded if name.startswith("nbvdata.")} <= SCHEMA_SIDE, loaded


def test_no_private_name_crosses_into_nbvtrain_the_benchmarks_or_the_examples():
    """No ``from nbvdata.x import _name`` and no ``module._name`` of a project module imported as a
    name, outside the package that defines it."""
    crossings = []
    files = [*(ROOT / "nbvtrain").glob("*.py"), *(ROOT / "benchmarks").glob("*.py"), *(ROOT / "recipes").glob("*.py"),
             *(ROOT / "examples").glob("*.py")]
    for path in files:
        tree = ast.parse(path.read_text())
        own = "nbvtrain" if path.parent.name == "nbvtrain" else None
        aliases = {}
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.split(".")[0] in PACKAGES \
                    and node.module.split(".")[0] != own:
                crossings += [f"{path.name}: from {node.module} import {a.name}" for a in node.names
                              if a.name.startswith("_")]
                aliases.update({a.asname or a.name: f"{node.module}.{a.name}" for a in node.names})
            elif isinstance(node, ast.Import):
                aliases.update({a.asname: a.name for a in node.names if a.asname and a.name.split(".")[0] in PACKAGES
                                and a.name.split(".")[0] != own})
        for node in ast.walk(tree):
            if isinstance(node, ast.Attribute) and isinstance(node.value, ast.Name) and node.value.id in aliases \
                    and node.attr.startswith("_") and not node.attr.startswith("__"):
                module = aliases[node.value.id]
                if (ROOT / (module.replace(".", "/") + ".py")).exists():
                    crossings.append(f"{path.name}: {module}.{node.attr}")
    assert crossings == []


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
    assert points == {"checkpoint": "nbvtrain.policy:CheckpointPolicy", "viewrank": "nbvtrain.policy:RankerPolicy"}
    for point in points.values():
        module, name = point.split(":")
        assert re.search(rf"^class {name}\b", (ROOT / (module.replace(".", "/") + ".py")).read_text(), re.M)


def test_pytest_runs_without_the_dash_plugin_warning():
    """open3d pulls in dash, whose pytest plugin warned on every run (pyproject: -p no:dash)."""
    result = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q", "tests/test_render.py"],
                            cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Warning" not in result.stdout + result.stderr


def test_the_documented_import_paths_still_work():
    """What the docs and users name: the modules, the old names of renamed ones (nbvtrain.data,
    nbvtrain.scene), the console scripts and the policy entry point."""
    import importlib
    import importlib.metadata

    names = {"nbvdata.shards": "Shard", "nbvdata.env": "ReconstructEnv", "nbvdata.policy": "load_policy",
             "nbvdata.generate": "generate", "nbvdata.sources": "mesh_sources", "nbvtrain.dataset": "NBVDataset",
             "nbvtrain.predict": "Predictor", "nbvtrain.plan": "plan", "nbvtrain.data": "load_shards",
             "nbvtrain.scene": "check_scene", "nbvtrain.planners": "build_planners"}
    for module, name in names.items():
        assert hasattr(importlib.import_module(module), name), f"{module}.{name}"
    assert importlib.import_module("nbvtrain.data").load_shards is importlib.import_module(
        "nbvtrain.training_data").load_shards
    scripts = {point.name: point.value for point in importlib.metadata.entry_points(group="console_scripts")
               if point.value.startswith(("nbvdata.", "nbvtrain."))}
    assert scripts == {"nbvdata": "nbvdata.cli:main", "nbvtrain": "nbvtrain.cli:main"}
    (policy,) = importlib.metadata.entry_points(group="nbvdata.policies", name="checkpoint")
    assert policy.load().__name__ == "CheckpointPolicy"


def _citing_files() -> dict[Path, str]:
    """What may cite a script, by path: the README, the docs, the tests, the released models' card,
    the configs, the packages and the scripts of benchmarks/ and recipes/."""
    paths = [ROOT / "README.md", ROOT / "nbvtrain" / "released" / "MODEL_CARD.md", *(ROOT / "docs").rglob("*.md"),
             *(ROOT / "tests").glob("*.py"), *(ROOT / "configs").glob("*"), *(ROOT / "nbvdata").glob("*.py"),
             *(ROOT / "nbvtrain").glob("*.py"), *(ROOT / "benchmarks").glob("*"), *(ROOT / "recipes").glob("*")]
    return {path: path.read_text() for path in paths if path.is_file()}


def test_benchmarks_hold_measurements_and_recipes_the_one_off_recipe():
    """Issue 58: benchmarks/ held the one-off recipe of issue 27's selection (selection.sh and the
    scripts it and docs/selection.md run, which write or read runs/selection) beside the
    measurements a maintainer reruns. No benchmark belongs to that recipe; recipes/README.md names
    every script of recipes/; every script of both folders is cited by another file (one that
    nothing cites is deleted, not kept)."""
    benchmarks = sorted(path for path in (ROOT / "benchmarks").iterdir() if path.suffix in (".py", ".sh"))
    recipes = sorted(path for path in (ROOT / "recipes").iterdir() if path.suffix in (".py", ".sh"))
    assert [path.name for path in benchmarks if "runs/selection" in path.read_text()] == []
    readme = (ROOT / "recipes" / "README.md").read_text()
    assert recipes and [path.name for path in recipes if f"`{path.name}`" not in readme] == []
    files = _citing_files()
    uncited = [f"{path.parent.name}/{path.name}" for path in benchmarks + recipes
               if not any(f"{path.parent.name}/{path.name}" in text or f'"{path.parent.name}" / "{path.name}"' in text
                          for other, text in files.items() if other != path)]
    assert uncited == []

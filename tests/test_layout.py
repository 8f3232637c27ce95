"""The project's shape: the folders are the stages of the one-way flow (``STAGES``, the tree
docs/design.md draws), every module in a stage folder (or on top, at a package's root), importing
only its own stage and earlier ones; nbvtrain's learning folder reads nbvdata only through its
schema side; old module paths import the new modules with a warning; nbvdata never imports torch;
no private name crosses into nbvtrain, the benchmarks, the recipes or the examples; benchmarks/
holds measurements and recipes/ the one-off recipe, each script cited; pytest runs quietly."""

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("nbvdata", "nbvtrain")

# The stages in the order data flows, each a folder ("" is the package's root: what is on top).
STAGES = (
    ("nbvdata", "core", "settings, words, files, users' arrays, view layouts and poses, paths, clouds"),
    ("nbvdata", "schema", "the shard schema, its summaries, published versions"),
    ("nbvdata", "simulation", "mesh -> views -> sensor -> grid -> coverage -> oracle -> scene -> episode"),
    ("nbvdata", "view", "pictures and Rerun recordings"),
    ("nbvdata", "datasets", "the generator, publishing, export, the authors' dataset"),
    ("nbvdata", "", "the command line and the Gymnasium environment"),
    ("nbvtrain", "networks", "the NBV-net family: networks, training, prediction, checkpoints"),
    ("nbvtrain", "ranking", "models of per-view rows: rankers, the surface prior, set-cover models"),
    ("nbvtrain", "planners", "the planners, one family a module, and their registry"),
    ("nbvtrain", "evaluation", "closed loop, the benchmark, its statistics and report"),
    ("nbvtrain", "robot", "a robot's scans and OctoMaps, plan"),
    ("nbvtrain", "", "release and the command line"),
)
ON_TOP = {"nbvdata": {"__init__", "__main__", "cli", "commandline", "commands", "env"},
          "nbvtrain": {"__init__", "__main__", "cli", "commands", "release"}}
"""The modules at a package's root (its top stage); any other module lies in a stage folder."""
LEARNING = STAGES.index(("nbvtrain", "networks", STAGES[6][2]))
SCHEMA_SIDE = {("nbvdata", "core"), ("nbvdata", "schema")}
"""What the learning folder may read of nbvdata."""


def _modules() -> dict[str, Path]:
    """Every module of the packages by full name (a folder's __init__ as the folder's own name)."""
    found = {}
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            found[".".join(parts)] = path
    return found


def stage_of(module: str) -> int:
    """The stage of ``nbvdata.simulation.grid`` (its folder's), or of a root module (the top);
    KeyError for a module in no stage folder, or at a root it does not belong to."""
    parts = module.split(".")
    package, rest = parts[0], parts[1:]
    if len(rest) <= 1 and not (rest and (ROOT / package / rest[0] / "__init__.py").exists()):
        if rest and rest[0] not in ON_TOP[package]:
            raise KeyError(f"{module}: at the root of {package}, which holds only {sorted(ON_TOP[package])}")
        return STAGES.index(next(stage for stage in STAGES if stage[:2] == (package, "")))
    for number, (owner, folder, _) in enumerate(STAGES):
        if owner == package and folder == rest[0]:
            return number
    raise KeyError(f"{module}: {package}/{rest[0]}/ is no stage folder")


def _imports(path: Path) -> set[str]:
    """Every module a file imports, at the top or inside a function, by full name."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            found.add(node.module)
            # `from nbvdata.schema import shards` imports the module nbvdata.schema.shards
            folder = ROOT / node.module.replace(".", "/")
            found.update(f"{node.module}.{alias.name}" for alias in node.names
                         if (folder / f"{alias.name}.py").exists() or (folder / alias.name / "__init__.py").exists())
    return found


def _graph() -> dict[str, set[str]]:
    """Module -> the project modules it imports (a package's import of its own root left out)."""
    modules = _modules()
    return {name: (_imports(path) & modules.keys()) - set(PACKAGES) for name, path in modules.items()}


def _stage_violations(graph: dict[str, set[str]]) -> list[str]:
    """"a -> b" for every import of a later stage, and of nbvdata beyond its schema side by a
    module of the learning folder."""
    bad = []
    for module, deps in sorted(graph.items()):
        for dep in sorted(deps):
            if stage_of(dep) > stage_of(module):
                bad.append(f"{module} ({_name(module)}) -> {dep} ({_name(dep)})")
            elif stage_of(module) == LEARNING and dep.startswith("nbvdata.") and \
                    STAGES[stage_of(dep)][:2] not in SCHEMA_SIDE:
                bad.append(f"{module} (learning) -> {dep}, not the schema side")
    return bad


def _name(module: str) -> str:
    package, folder, _ = STAGES[stage_of(module)]
    return f"{package}/{folder}" if folder else f"{package} top"


def test_every_module_lies_in_a_stage_folder():
    problems = []
    for module in _modules():
        try:
            stage_of(module)
        except KeyError as error:
            problems.append(str(error))
    assert problems == []
    folders = {path.parent.relative_to(ROOT).as_posix() for path in _modules().values()}
    assert folders == {f"{package}/{folder}".rstrip("/") for package, folder, _ in STAGES}


def test_a_module_outside_every_stage_folder_is_caught():
    for stray in ("nbvdata.shards", "nbvtrain.misc.tools", "nbvtrain.planners_extra"):
        with pytest.raises(KeyError):
            stage_of(stray)


def test_imports_flow_one_way_through_the_stages():
    """Top-level and function-level imports alike (``_imports``)."""
    assert _stage_violations(_graph()) == []


def test_a_reversed_import_is_caught():
    """The check itself: the shard schema importing the job, or a learning module the simulator, fails."""
    graph = _graph()
    graph["nbvdata.schema.shards"] = graph["nbvdata.schema.shards"] | {"nbvdata.datasets.generate"}
    graph["nbvtrain.networks.training_data"] = graph["nbvtrain.networks.training_data"] | {"nbvdata.simulation.grid"}
    graph["nbvtrain.planners.base"] = graph["nbvtrain.planners.base"] | {"nbvtrain.release"}
    assert _stage_violations(graph) == [
        "nbvdata.schema.shards (nbvdata/schema) -> nbvdata.datasets.generate (nbvdata/datasets)",
        "nbvtrain.networks.training_data (learning) -> nbvdata.simulation.grid, not the schema side",
        "nbvtrain.planners.base (nbvtrain/planners) -> nbvtrain.release (nbvtrain top)"]


def test_the_design_page_draws_the_same_tree():
    page = (ROOT / "docs" / "design.md").read_text()
    tree = page[page.index("```\nnbvdata/"):]
    tree = tree[:tree.index("```", 3)]
    drawn, package = [], None
    for line in tree.splitlines()[1:]:
        if re.match(r"^nbv(data|train)/", line):
            package = line.split("/")[0]
        elif re.match(r"^  \w+/", line) and not line.strip().startswith("released/"):
            drawn.append((package, line.split("/")[0].strip()))
    assert drawn == [(package, folder) for package, folder, _ in STAGES if folder], drawn
    on_top = " ".join(tree.splitlines())
    assert all(f"{module}.py" in on_top for modules in ON_TOP.values() for module in modules
               if not module.startswith("_")), "docs/design.md: name every module on top"


def test_every_folder_says_what_it_holds():
    for package, folder, _ in STAGES:
        if folder:
            init = ROOT / package / folder / "__init__.py"
            doc = ast.get_docstring(ast.parse(init.read_text()))
            assert doc and doc.splitlines()[0].endswith("."), f"{init}: a first line saying what the folder holds"


def test_no_module_grows_past_600_lines_without_a_reason():
    long = [f"{module} ({len(path.read_text().splitlines())} lines)" for module, path in _modules().items()
            if len(path.read_text().splitlines()) > 650 and "Longer than" not in (ast.get_docstring(
                ast.parse(path.read_text())) or "")]
    assert long == [], "split them, or say in the docstring why one module (\"Longer than ... because ...\")"


def test_reading_shards_loads_no_simulator():
    """``import nbvtrain.networks.dataset`` (a torch Dataset over HDF5 files) loads neither open3d,
    trimesh nor numba, nor any simulation module."""
    code = ("import sys, nbvtrain.networks.dataset\n"
            "print(' '.join(sorted(m for m in sys.modules if m.split('.')[0] in "
            "('open3d', 'trimesh', 'numba', 'nbvdata', 'nbvtrain'))))")
    loaded = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert not {name for name in loaded if name.split(".")[0] in ("open3d", "trimesh", "numba")}, loaded
    side = {name for name in loaded if name.startswith("nbvdata.") and name.count(".") >= 2}
    assert all(tuple(name.split(".")[:2]) in SCHEMA_SIDE for name in side), loaded


def test_the_old_module_paths_import_the_new_modules_with_a_warning_once():
    """Every module moved into a folder (0.2) keeps its old path for one minor release: the same
    module object, a DeprecationWarning naming the new path the first time, none after; no file
    stands at an old path."""
    import nbvdata.core.moved
    import nbvtrain

    table = nbvdata.core.moved.MOVED | nbvtrain.MOVED
    assert not [old for old in table if (ROOT / (old.replace(".", "/") + ".py")).exists()]
    code = f"""
import importlib, warnings
table = {table!r}
problems = []
for old, new in table.items():
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        module = importlib.import_module(old)
        again = importlib.import_module(old)
    named = [str(w.message) for w in caught if issubclass(w.category, DeprecationWarning) and new in str(w.message)]
    if module is not importlib.import_module(new) or again is not module or len(named) != 1:
        problems.append((old, new, named))
print(problems)
"""
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=600)
    assert done.returncode == 0 and done.stdout.strip() == "[]", done.stdout + done.stderr[-2000:]
    old = subprocess.run([sys.executable, "-W", "error::DeprecationWarning", "-c",
                          "from nbvdata.shards import Shard"], capture_output=True, text=True, cwd=ROOT)
    assert old.returncode == 1 and "nbvdata.shards has moved to nbvdata.schema.shards" in old.stderr


def test_no_private_name_crosses_into_nbvtrain_the_benchmarks_or_the_examples():
    """No ``from nbvdata.x import _name`` and no ``module._name`` of a project module imported as a
    name, outside the package that defines it."""
    crossings = []
    files = [*(ROOT / "nbvtrain").rglob("*.py"), *(ROOT / "benchmarks").glob("*.py"), *(ROOT / "recipes").glob("*.py"),
             *(ROOT / "examples").glob("*.py")]
    for path in files:
        tree = ast.parse(path.read_text())
        own = "nbvtrain" if "nbvtrain" in path.relative_to(ROOT).parts[:1] else None
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
                if module in _modules():
                    crossings.append(f"{path.name}: {module}.{node.attr}")
    assert crossings == []


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
    for path in (ROOT / "nbvdata").rglob("*.py"):
        bad = {name for name in _imports(path) if name.split(".")[0] in ("torch", "nbvtrain")}
        named = {node.value for node in ast.walk(ast.parse(path.read_text()))
                 if isinstance(node, ast.Constant) and isinstance(node.value, str)
                 and re.fullmatch(r"(torch|nbvtrain)(\.\w+)*(:\w+)?", node.value)}
        assert not bad and not named, f"{path.name} imports {bad or named}"


def test_nbvtrain_registers_its_policy_provider():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    points = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]["nbvdata.policies"]
    assert points == {"checkpoint": "nbvtrain.planners.provider:CheckpointPolicy",
                      "viewrank": "nbvtrain.planners.provider:RankerPolicy"}
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
    """What the docs and users name: the modules at their paths, the names the old paths still give
    (``test_the_old_module_paths_...``), the console scripts and the policy entry points."""
    import importlib
    import importlib.metadata

    names = {"nbvdata.schema.shards": "Shard", "nbvdata.env": "ReconstructEnv",
             "nbvdata.simulation.policy": "load_policy", "nbvdata.datasets.generate": "generate",
             "nbvdata.simulation.sources": "mesh_sources", "nbvtrain.networks.dataset": "NBVDataset",
             "nbvtrain.networks.predict": "Predictor", "nbvtrain.robot.plan": "plan",
             "nbvtrain.networks.training_data": "load_shards", "nbvtrain.networks.trained_scene": "check_scene",
             "nbvtrain.planners": "build_planners", "nbvtrain.release": "released_checkpoint"}
    for module, name in names.items():
        assert hasattr(importlib.import_module(module), name), f"{module}.{name}"
    scripts = {point.name: point.value for point in importlib.metadata.entry_points(group="console_scripts")
               if point.value.startswith(("nbvdata.", "nbvtrain."))}
    assert scripts == {"nbvdata": "nbvdata.cli:main", "nbvtrain": "nbvtrain.cli:main"}
    for name, cls in (("checkpoint", "CheckpointPolicy"), ("viewrank", "RankerPolicy")):
        (policy,) = importlib.metadata.entry_points(group="nbvdata.policies", name=name)
        assert policy.load().__name__ == cls


def _citing_files() -> dict[Path, str]:
    """What may cite a script, by path: the README, the docs, the tests, the released models' card,
    the configs, the packages and the scripts of benchmarks/ and recipes/."""
    paths = [ROOT / "README.md", ROOT / "nbvtrain" / "released" / "MODEL_CARD.md", *(ROOT / "docs").rglob("*.md"),
             *(ROOT / "tests").glob("*.py"), *(ROOT / "configs").glob("*"), *(ROOT / "nbvdata").rglob("*.py"),
             *(ROOT / "nbvtrain").rglob("*.py"), *(ROOT / "benchmarks").glob("*"), *(ROOT / "recipes").glob("*")]
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

"""Packaging: torch is the optional ``train`` extra, nbvdata runs without it, nbvtrain says how
to install it, and CI runs exactly the README's test command."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
NO_TORCH = "import sys; sys.modules['torch'] = None  # any `import torch` now raises ImportError\n"


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", NO_TORCH + code], capture_output=True, text=True, timeout=120,
                          cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT)))


def test_torch_is_an_optional_extra():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not [dep for dep in project["dependencies"] if re.match(r"torch\b", dep)]
    extras = project["optional-dependencies"]
    assert "torch>=2.2" in extras["train"] and "torch>=2.2" in extras["test"]


def test_every_nbvdata_module_imports_without_torch():
    done = _python(
        "import pkgutil, importlib, nbvdata\n"
        "names = [m.name for m in pkgutil.walk_packages(nbvdata.__path__, 'nbvdata.') if m.name != 'nbvdata.__main__']\n"
        "for name in names:\n"
        "    importlib.import_module(name)\n"
        "assert sys.modules['torch'] is None\n"
        "print(len(names))\n")
    assert done.returncode == 0, done.stderr
    files = list((ROOT / "nbvdata").rglob("*.py"))
    assert int(done.stdout) == len(files) - 2  # every module and folder, all but nbvdata's own __init__ and __main__


def test_the_publish_extra_checks_and_loads_what_nbvdata_writes_without_it():
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    tools = {"mlcroissant>=1.1", "datasets>=4.1", "cffconvert>=2.0"}
    extras = project["optional-dependencies"]
    assert tools <= set(extras["publish"]) and tools <= set(extras["test"])
    assert not {re.split(r"[<>=\[]", dep)[0] for dep in project["dependencies"]} & {"mlcroissant", "datasets",
                                                                                  "cffconvert", "pandas", "pyarrow"}
    done = _python("sys.modules.update(dict.fromkeys(['mlcroissant', 'datasets', 'cffconvert', 'pandas', 'pyarrow']))\n"
                   "import nbvdata.cli, nbvdata.datasets.publish, nbvdata.datasets.share\n")
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("argv", [["predict", "g.npy", "--checkpoint", "best.pt"], ["--help"], []])
def test_nbvtrain_without_torch_names_the_install_command(argv):
    done = _python(f"from nbvtrain.cli import main\nsys.exit(main({argv!r}))\n")
    err = done.stderr.strip()
    assert done.returncode == 2 and len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith("nbvtrain: error: nbvtrain needs PyTorch") and 'pip install -e ".[train]"' in err


def test_ci_runs_the_readme_commands():
    readme = (ROOT / "README.md").read_text()
    install, test = re.findall(r"```bash\n(python3 -m venv .*)\n```", readme)[:2]
    for command, extra in ((install, "train"), (test, "test")):  # the pinned CPU wheel this machine holds
        assert f'pip install torch==2.13.0 -e ".[{extra}]"' in command
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    command = ci[ci.index("# The README's test command:") + 1]
    assert test.endswith(" && " + command) and command.startswith("pip install")


def test_gymnasium_is_an_optional_extra_that_nbvdata_env_names():
    tomllib = pytest.importorskip("tomllib")  # Python 3.11+
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    assert not [dep for dep in project["dependencies"] if dep.startswith("gymnasium")]
    extras = project["optional-dependencies"]
    assert "gymnasium>=1.0" in extras["rl"] and "gymnasium>=1.0" in extras["test"]
    done = _python(
        "sys.modules['gymnasium'] = None\n"
        "import pkgutil, importlib, nbvdata\n"
        "for m in pkgutil.iter_modules(nbvdata.__path__, 'nbvdata.'):\n"
        "    if m.name not in ('nbvdata.__main__', 'nbvdata.env'):\n"
        "        importlib.import_module(m.name)\n"
        "try:\n"
        "    import nbvdata.env\n"
        "except ImportError as error:\n"
        "    print(error)\n")
    assert done.returncode == 0, done.stderr
    message = done.stdout.strip()
    assert len(message.splitlines()) == 1 and message.startswith("nbvdata.env needs gymnasium")
    assert 'pip install -e ".[rl]"' in message

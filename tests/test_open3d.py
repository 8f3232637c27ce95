"""open3d imports on a machine without a system libusb, through nbvdata.simulation._open3d."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _python(code: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True, timeout=120)


def test_a_script_that_imports_open3d_itself_works_after_the_documented_line():
    """README: `from nbvdata.simulation._open3d import open3d` (or `import nbvdata.simulation._open3d`) before `import open3d`."""
    result = _python("import nbvdata.simulation._open3d\nimport open3d\nprint(open3d.geometry.TriangleMesh)")
    assert result.returncode == 0, result.stderr


def test_a_failed_import_says_how_to_fix_it():
    result = _python("import sys\nsys.modules['open3d'] = None  # as if it could not load\nimport nbvdata.simulation._open3d")
    last = result.stderr.strip().splitlines()[-1]
    assert last.startswith("ImportError: cannot import open3d (") and "pip install open3d libusb-package" in last
    assert "from nbvdata.simulation._open3d import open3d" in last

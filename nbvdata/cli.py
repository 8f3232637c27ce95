"""The ``nbvdata`` command line.

Each subcommand is a plain function of parsed arguments returning an exit status; expected
user errors (a bad config key, a broken mesh, a missing file) print one line naming the fix
and exit with status 2, never a traceback.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

import numpy as np

from nbvdata import __version__
from nbvdata.config import ConfigError, SimConfig, load_config
from nbvdata.mesh import MeshError, ObjectMesh, load_mesh
from nbvdata.shapes import BUILTIN_SHAPES, builtin_object


class UsageError(Exception):
    """A user error the command reports in one line."""


def _add_config_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, help="YAML file with settings (see configs/default.yaml)")
    parser.add_argument("--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="override one setting, e.g. --set views.count=1000 (repeatable)")


def _add_object_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--mesh", type=Path, help="mesh file (obj, ply, off, stl, glb, gltf)")
    parser.add_argument("--shape", default="mug", choices=sorted(BUILTIN_SHAPES),
                        help="built-in shape used when no --mesh is given (default: mug)")


def _load_object(args: argparse.Namespace, config: SimConfig) -> ObjectMesh:
    return load_mesh(args.mesh, config.mesh) if args.mesh else builtin_object(args.shape, config.mesh)


def _parse_indices(text: str, count: int) -> list[int]:
    try:
        indices = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        raise UsageError(f"--views {text!r}: expected comma-separated view indices, e.g. --views 0,120,340") from None
    bad = [i for i in indices if not 0 <= i < count]
    if bad:
        raise UsageError(f"--views: indices {bad} out of range; the view set has {count} views (0..{count - 1})")
    return indices


def cmd_demo(args: argparse.Namespace) -> int:
    """Scan an object from a few views, integrate, report coverage, and render the state."""
    from nbvdata.render import render_state
    from nbvdata.scene import Scene

    config = load_config(SimConfig, args.config, args.overrides)
    obj = _load_object(args, config)
    rng = np.random.default_rng(args.seed)
    scene = Scene.build(obj, config, rng)
    grid = scene.new_grid()
    views = rng.choice(len(scene.views), size=min(args.scans, len(scene.views)), replace=False)
    covered = np.zeros(len(scene.coverage.points), dtype=bool)
    print(f"{obj.source}: {len(obj.mesh.faces)} faces, {len(scene.views)} candidate views, "
          f"{int(scene.coverage.observable.sum())}/{len(scene.coverage.points)} reference points observable")
    for step, view in enumerate(views, start=1):
        start = time.perf_counter()
        scan = scene.scanner.scan(scene.views[int(view)], rng)
        scene.integrate(grid, scan)
        elapsed = time.perf_counter() - start
        covered |= scene.coverage.covered_by(scan.hit_points)
        total, observable = scene.coverage.coverage(covered)
        print(f"scan {step}: view {int(view):4d}  {int(scan.hit.sum()):5d} returns  "
              f"coverage {100 * total:5.1f}%  observable {100 * observable:5.1f}%  "
              f"scan+integrate {1e3 * elapsed:6.1f} ms  {grid.counts()}")
    out = render_state(grid.probabilities(), config.grid.extent, args.out, scene.views,
                       highlight=int(views[-1]), others=[int(v) for v in views[:-1]],
                       title=f"{obj.source}: {len(views)} scans")
    print(f"wrote {out}")
    return 0


def cmd_show(args: argparse.Namespace) -> int:
    """Render a saved grid (.npy), or the grid after scanning an object from given views."""
    from nbvdata.render import render_state
    from nbvdata.views import view_sphere

    config = load_config(SimConfig, args.config, args.overrides)
    views = view_sphere(config.views)
    if args.grid is not None:
        probabilities = _load_grid_file(args.grid, config.grid.size)
        title = args.grid.name
    else:
        from nbvdata.grid import OccupancyGrid
        from nbvdata.sensor import MeshScanner

        obj = _load_object(args, config)
        scanner = MeshScanner(obj.mesh, config.sensor)
        grid = OccupancyGrid(config.grid)
        rng = np.random.default_rng(args.seed)
        for index in _parse_indices(args.views, len(views)):
            grid.integrate(scanner.scan(views[index], rng), config.sensor.far)
        probabilities = grid.probabilities()
        title = f"{obj.source}, views {args.views}"
    highlight = None
    if args.highlight is not None:
        highlight = _parse_indices(str(args.highlight), len(views))[0]
    out = render_state(probabilities, config.grid.extent, args.out, views, highlight=highlight, title=title)
    print(f"wrote {out}")
    return 0


def _load_grid_file(path: Path, size: int) -> np.ndarray:
    if not path.is_file():
        raise UsageError(f"{path}: no such file")
    try:
        array = np.load(path, allow_pickle=False)
    except Exception as error:
        raise UsageError(f"{path}: not a readable .npy array ({type(error).__name__})") from None
    if array.size != size ** 3:
        raise UsageError(f"{path}: holds {array.size} values, a {size}^3 grid needs {size ** 3}")
    return array.reshape(size, size, size).astype(np.float32)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="nbvdata", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"nbvdata {__version__}")
    parser.add_argument("-v", "--verbose", action="store_true", help="log debug messages")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="scan an object from a few random views and render the grid to PNG")
    _add_object_options(demo)
    _add_config_options(demo)
    demo.add_argument("--scans", type=int, default=4, help="number of scans (default 4)")
    demo.add_argument("--seed", type=int, default=0, help="seed for the views, noise and reference points")
    demo.add_argument("--out", type=Path, default=Path("nbv_demo.png"), help="PNG to write")
    demo.set_defaults(func=cmd_demo)

    show = sub.add_parser("show", help="render a grid with the candidate views to PNG")
    show.add_argument("grid", type=Path, nargs="?", help="a .npy grid (n^3 values, authors' encoding)")
    _add_object_options(show)
    _add_config_options(show)
    show.add_argument("--views", default="0", help="without a grid file: views to scan from, e.g. 0,120,340")
    show.add_argument("--highlight", type=int, help="index of the view to draw as a red arrow")
    show.add_argument("--seed", type=int, default=0, help="seed for sensor noise")
    show.add_argument("--out", type=Path, default=Path("nbv_show.png"), help="PNG to write")
    show.set_defaults(func=cmd_show)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.WARNING,
                        format="%(levelname)s %(name)s: %(message)s")
    try:
        return args.func(args)
    except (ConfigError, MeshError, UsageError) as error:
        print(f"nbvdata {args.command}: error: {error}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"nbvdata {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

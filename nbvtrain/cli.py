"""The ``nbvtrain`` command line: training, prediction and evaluation of NBV networks.

Its commands (fit, predict, evaluate) build on the shard schema of ``nbvdata generate`` and
are not written yet; until then the command only reports its version.
"""

from __future__ import annotations

import argparse
import sys

from nbvtrain import __version__


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="nbvtrain", description=__doc__.splitlines()[0])
    parser.add_argument("--version", action="version", version=f"nbvtrain {__version__}")
    return parser


def main(argv: list[str] | None = None) -> int:
    build_parser().parse_args(argv)
    print("nbvtrain: no commands yet (fit, predict and evaluate need the nbvdata shard schema first)",
          file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main())

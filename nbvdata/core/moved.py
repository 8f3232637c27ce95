"""Old module paths, kept for one minor release after the move into role folders (0.2): ``install``
makes ``import OLD`` and ``from OLD import name`` give the module at its new path - the same
module object, so ``OLD.name is NEW.name`` - with a ``DeprecationWarning`` naming the new path,
once per old path. No file stands at an old path; ``MOVED`` is the table of nbvdata's, nbvtrain
installs its own."""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

MOVED = {
    "nbvdata._open3d": "nbvdata.simulation._open3d",
    "nbvdata.authors": "nbvdata.datasets.authors",
    "nbvdata.card": "nbvdata.datasets.card",
    "nbvdata.claims": "nbvdata.datasets.claims",
    "nbvdata.cloud": "nbvdata.core.cloud",
    "nbvdata.config": "nbvdata.core.config",
    "nbvdata.coverage": "nbvdata.simulation.coverage",
    "nbvdata.episode": "nbvdata.simulation.episode",
    "nbvdata.errors": "nbvdata.core.errors",
    "nbvdata.export": "nbvdata.datasets.export",
    "nbvdata.files": "nbvdata.core.files",
    "nbvdata.generate": "nbvdata.datasets.generate",
    "nbvdata.grid": "nbvdata.simulation.grid",
    "nbvdata.gridstats": "nbvdata.datasets.gridstats",
    "nbvdata.layout_scvp": "nbvdata.core.layout_scvp",
    "nbvdata.layout_tammes": "nbvdata.core.layout_tammes",
    "nbvdata.logodds": "nbvdata.core.logodds",
    "nbvdata.manifest": "nbvdata.schema.manifest",
    "nbvdata.mesh": "nbvdata.simulation.mesh",
    "nbvdata.oracle": "nbvdata.simulation.oracle",
    "nbvdata.paths": "nbvdata.core.paths",
    "nbvdata.policy": "nbvdata.simulation.policy",
    "nbvdata.publish": "nbvdata.datasets.publish",
    "nbvdata.render": "nbvdata.view.render",
    "nbvdata.rerun": "nbvdata.view.rerun",
    "nbvdata.scene": "nbvdata.simulation.scene",
    "nbvdata.sensor": "nbvdata.simulation.sensor",
    "nbvdata.setcover": "nbvdata.simulation.setcover",
    "nbvdata.shapes": "nbvdata.simulation.shapes",
    "nbvdata.shards": "nbvdata.schema.shards",
    "nbvdata.sources": "nbvdata.simulation.sources",
    "nbvdata.summary": "nbvdata.schema.summary",
    "nbvdata.text": "nbvdata.core.text",
    "nbvdata.userarrays": "nbvdata.core.userarrays",
    "nbvdata.viewfeatures": "nbvdata.simulation.viewfeatures",
    "nbvdata.views": "nbvdata.core.views",
}
"""Old module path -> new module path, nbvdata's."""


class MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """The import hook behind ``install``: a finder for the old paths whose loader hands out the new module."""

    def __init__(self) -> None:
        self.table: dict[str, str] = {}
        self.warned: set[str] = set()

    def find_spec(self, fullname, path=None, target=None):
        if fullname not in self.table:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        new = self.table[spec.name]
        if spec.name not in self.warned:
            self.warned.add(spec.name)
            warnings.warn(f"{spec.name} has moved to {new}: import it from there (the old path is kept until the "
                          "next minor release)", DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)

    def exec_module(self, module) -> None:
        """Nothing to run: the module at the new path is loaded already."""


FINDER = MovedFinder()


def install(table: dict[str, str]) -> None:
    """Serve the old paths of ``table`` (old -> new) through ``FINDER``, installed once."""
    FINDER.table.update(table)
    if FINDER not in sys.meta_path:
        sys.meta_path.append(FINDER)

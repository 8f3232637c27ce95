"""nbvdata: simulated reconstructions labelled with the ground-truth next-best-view.

Folders are the stages, data flowing one way (docs/design.md states them once, and
tests/test_layout.py holds the imports to them): ``core`` < ``schema`` < ``simulation`` <
``view`` < ``datasets``, with the command line and the Gymnasium environment on top (``cli``,
``commandline``, ``env``). Old module paths (before 0.2) still import, with a DeprecationWarning
(``nbvdata.core.moved``).
"""

from nbvdata.core.moved import MOVED, install

__version__ = "0.1.0"

install(MOVED)

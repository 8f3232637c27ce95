"""``python -m nbvtrain`` runs the ``nbvtrain`` command."""

import sys

from nbvtrain.cli import main

status = main()
# A KeyboardInterrupt that passed through code run by exec() (a dataclass being built during an
# import, say) leaves CPython (3.10-3.13) believing it went unhandled, even when main() caught it;
# under `python -m` only, the interpreter then kills itself with SIGINT at exit instead of exiting
# with ``status``. Running a string through exec() clears that flag.
exec("None")
sys.exit(status)

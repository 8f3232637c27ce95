"""``python -m nbvdata`` runs the ``nbvdata`` command."""

import sys

from nbvdata.cli import main

status = main()
exec("None")  # see nbvtrain/__main__.py: exit with ``status``, not by SIGINT, after a caught Ctrl-C
sys.exit(status)

"""``python -m nbvdata`` runs the ``nbvdata`` command."""

import sys

from nbvdata.cli import main

sys.exit(main())

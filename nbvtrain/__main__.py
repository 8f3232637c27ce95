"""python -m nbvtrain"""

import sys

from nbvtrain.cli import main

sys.exit(main())

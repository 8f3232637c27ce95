"""Old name of ``nbvtrain.training_data`` (shards loaded into memory for training), kept for
scripts that import it (docs/training.md once named ``nbvtrain.data.load_shards``)."""

from nbvtrain.training_data import *  # noqa: F401,F403
from nbvtrain.training_data import __all__  # noqa: F401

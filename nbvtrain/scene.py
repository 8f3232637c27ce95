"""Old name of ``nbvtrain.trained_scene`` (the scene a checkpoint was trained in), kept for
scripts that import it (``nbvtrain.scene.check_scene``)."""

from nbvtrain.trained_scene import *  # noqa: F401,F403
from nbvtrain.trained_scene import __all__  # noqa: F401

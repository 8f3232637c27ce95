"""The released model: the checkpoint commands use when none is given.

One function, ``released_checkpoint``, is where commands look for it (``nbvtrain plan`` without
``--checkpoint``). No model is released yet (the learned-planner issue will release one and
fill this in), so today it says so in one line and names the fix.
"""

from __future__ import annotations

from pathlib import Path

from nbvdata.config import ConfigError


class NoReleasedModel(ConfigError):
    """No released model is available; the message says what to pass instead."""


def released_checkpoint() -> Path:
    """The released model's checkpoint file; ``NoReleasedModel`` while none is released."""
    raise NoReleasedModel("no model is released yet: pass --checkpoint runs/NAME/best.pt (a checkpoint written by "
                          "nbvtrain fit)")

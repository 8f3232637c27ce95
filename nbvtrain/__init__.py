"""nbvtrain: the NBV-net family, trained on nbvdata shards, and closed-loop evaluation."""

__version__ = "0.1.0"

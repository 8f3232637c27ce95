"""Models of per-view rows: the ranker of candidate views, the surface prior, set-cover models."""

"""A robot's scans and OctoMaps, and plan: the next view in its world frame."""

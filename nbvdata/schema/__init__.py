"""The shard schema, its summaries and published versions: with the core, what nbvtrain learns from."""

"""The NBV-net family: networks, training data, fit, checkpoints, prediction, baselines, RL."""

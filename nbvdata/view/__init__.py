"""Looking at states and runs: pictures and Rerun recordings."""

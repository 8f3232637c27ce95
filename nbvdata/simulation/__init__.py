"""The simulated reconstructions and their exact labels: mesh, sensor, grid, oracle, scene, episode."""

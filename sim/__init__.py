"""bodebench simulator: plants and the simulated servo controller."""

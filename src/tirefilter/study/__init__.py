"""Studies over many co-simulated trials: the Monte-Carlo engine and the stiffness study."""

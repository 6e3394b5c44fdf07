"""SubgoalVLA policy: config, model pieces, LeRobot policy and processors."""

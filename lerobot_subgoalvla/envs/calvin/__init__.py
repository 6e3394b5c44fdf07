"""CALVIN as a LeRobot environment: simulator, task oracle, scripted expert, long-horizon chains."""

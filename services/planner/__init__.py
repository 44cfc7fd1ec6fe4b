"""The reference planner: A* on the occupancy grid, answering ``nav/plan``."""

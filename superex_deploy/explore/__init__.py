"""Exploration engine: observed map, frontiers, motion planning, planners, episodes and metrics."""

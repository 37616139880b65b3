"""Planning: where the robot goes next and how it gets there.

* :mod:`.motion`: the planning map (traversable cells, wall-proximity costs), Dijkstra travel costs and paths, the
  step along a path.
* :mod:`.frontiers`: frontier clusters of the observed map.
* :mod:`.goal_choice`: the goal kept or replaced, and when a goal counts as reached.
* :mod:`.goal_policy`: when a goal is given up (blacklisted) and when a better one replaces it.
* :mod:`.bounds`: the exploration region, a polygon in metres, and the frontiers cut to it.
* :mod:`.visibility`, :mod:`.viewpoint_gains`, :mod:`.expected_visibility`: what a viewpoint would see on a
  predicted map (the gains the planners score).
* :mod:`.planners`: one module per planner (nearest frontier, IG-Hector, UPEN, MapEx, SuperEx) and
  :func:`~superex_deploy.onboard.planning.planners.make_planner`.
"""

"""What passes between a robot (or the simulator) and the onboard explorer: SI units, ROS-like fields.

Both sides import this module; it holds no ground truth and reads none.

Frames
------
The **map frame** is ROS's: ``x`` east, ``y`` north (up on the image), yaw counter-clockwise from ``+x``, metres and
radians. Its grid (:class:`MapFrame`) is ``[row, col]`` with row 0 at the *top* of the image, as everywhere in
SuperEx; ``origin_xy`` is the map-frame position of the grid's lower-left corner (ROS ``map_server``'s ``origin``).
Cell ``(r, c)`` covers ``x in [ox + c res, ox + (c + 1) res)`` and ``y in [oy + (H - r - 1) res, oy + (H - r) res)``.

Internally the grid geometry (:mod:`superex_deploy.geometry`) uses continuous ``(y, x)`` in cells with ``y`` *down*
and angles measured towards ``+row``; a map-frame heading ``phi`` is the grid angle ``-phi``.

Limits
------
What enters here is refused with one ``ValueError`` before anything is allocated or integrated:

* **Map size**: a grid of more than :func:`max_map_cells` cells (default :data:`MAX_MAP_CELLS`, 25 million: 5000 x
  5000 cells, 500 m square at 0.1 m; the environment variable ``SUPEREX_MAX_MAP_CELLS`` raises or lowers it), or a
  resolution finer than :data:`MIN_RESOLUTION_M` (1 mm: the planner's per-cell neighbourhoods, robot radius and
  wall-cost range, are counted in cells, and at 0.1 mm the wall-cost disc alone holds 4e8 cells). The map loader
  (:func:`superex_deploy.maps.load_map`) applies the same rule to an image's header before decoding its pixels.
* **Time stamps** (:func:`check_stamp`): finite, ``>= 0`` and at most :data:`MAX_STAMP_S` (``2**31 - 1`` s: the
  ``int32`` seconds of a ROS 2 ``builtin_interfaces/Time``, so that every observation can be recorded).
* **Headings** (:class:`Pose2D`): finite and ``|yaw| <= MAX_ABS_YAW`` (1e6 rad; beyond, a float64 angle is
  coarser than 1e-10 rad and its direction is noise), normalised to ``(-pi, pi]`` (a yaw already there is kept
  bit for bit).

Precision
---------
Fields that ``sensor_msgs/LaserScan`` holds as ``float32`` (angles, range limits, ranges) are stored at float32
precision here too, so that a recorded observation (see :mod:`superex_deploy.recording`) is bit-identical to the
one the explorer saw.
"""

from __future__ import annotations

from superex_deploy.messages.frame import MapFrame, Pose2D, grid_angles
from superex_deploy.messages.limits import (MAX_ABS_YAW, MAX_MAP_CELLS, MAX_MAP_CELLS_ENV, MAX_STAMP_S, MIN_RESOLUTION_M,
                                           check_map_size, check_stamp, max_map_cells)
from superex_deploy.messages.observation import (DONE, EXPLORING, NO_REACHABLE_FRONTIER, RETURNING, STATUSES,
                                                 WAITING_FOR_SCAN, Command, Observation)
from superex_deploy.messages.occupancy import OCCUPANCY_UNKNOWN, OccupancyGridMessage, PoseCovariance, same_resolution
from superex_deploy.messages.sensors import LaserScan, SpadFrame

__all__ = ["MapFrame", "Pose2D", "LaserScan", "SpadFrame", "Observation", "Command", "grid_angles",
           "MAX_MAP_CELLS", "MAX_MAP_CELLS_ENV", "MIN_RESOLUTION_M", "MAX_STAMP_S", "MAX_ABS_YAW", "max_map_cells",
           "check_map_size", "check_stamp", "OccupancyGridMessage", "PoseCovariance", "OCCUPANCY_UNKNOWN",
           "same_resolution", "STATUSES", "WAITING_FOR_SCAN", "EXPLORING", "NO_REACHABLE_FRONTIER", "RETURNING",
           "DONE"]

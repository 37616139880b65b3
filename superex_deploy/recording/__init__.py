"""Record an exploration episode to an MCAP file and read it back: every observation, every command, the map.

The file uses the ``ros2`` MCAP profile (CDR messages with ``ros2msg`` schemas), so Foxglove, the ``mcap`` CLI and
ROS 2 tools read it. Topics (one message of each per step unless noted; ``sequence`` = the explorer's step):

============  ==================================  =====================================================================
topic         type                                content
============  ==================================  =====================================================================
``/pose``     ``geometry_msgs/msg/PoseStamped``   the robot's pose (frame ``map``; yaw as a quaternion about ``z``)
``/scan``     ``sensor_msgs/msg/LaserScan``       the line-of-sight scan (frame ``base_scan``, aligned with the robot)
``/spad``     ``superex_msgs/msg/SpadFrame``      the SPAD frame, when the step has one (schema :data:`SPAD_FRAME_MSG`)
``/command``  ``superex_msgs/msg/ExplorerCommand``  the explorer's answer: goal cell and position, flags (schema below)
``/plan``     ``nav_msgs/msg/Path``               the commanded path (frame ``map``)
``/map``      ``nav_msgs/msg/OccupancyGrid``      the explorer's map (-1 unknown, 0 free, 100 occupied) every
                                                  ``map_every`` steps and at the last one
============  ==================================  =====================================================================

A robot's observation may carry two more inputs, recorded (and replayed) only when present: ``/slam_map``
(``nav_msgs/msg/OccupancyGrid``, the SLAM map the explorer read; ``/scan`` is absent on a step without a scan) and
``/pose_covariance`` (``geometry_msgs/msg/PoseWithCovarianceStamped``: x, y, yaw entries of the 6 x 6, the rest 0).

The topics, their schemas and how each message is built from a step are one table,
:data:`~superex_deploy.recording.channels.CHANNELS`, which the live view (:mod:`superex_deploy.recording.live`:
``superex explore --live``) serves too, with four topics of its own (``/tf``, ``/goal``, ``/prediction``,
``/evidence``).

A metadata record ``superex.episode`` holds the format version (:data:`FORMAT_VERSION`) and what a replay needs to
rebuild the explorer (map frame, planner and its whole configuration, predictor, seed, sensor model, NLOS and
explorer configuration, profile: :mod:`superex_deploy.recording.metadata`, every configuration as its ``to_json``
writes it), each value a JSON string whose type is fixed (:data:`METADATA_TYPES`; checked when writing and when
reading). A recording of another format is refused when read; one of an earlier format is rewritten into this one
by ``superex convert-recording`` (:mod:`superex_deploy.recording.convert`). The SPAD
frame's arrays are little-endian byte blobs (``uint8[]``): the CDR encoders write numeric arrays element by element,
and a frame holds ~160,000 non-zero bins.

The file is written to ``PATH.part`` and renamed to ``PATH`` when the episode ends; an episode that fails leaves no
file behind. An episode stopped by a signal (SIGINT or SIGTERM raising ``KeyboardInterrupt``, as ``superex`` and
:func:`superex_deploy.parallel.stop_signals` make them) is closed as a valid file of every whole step recorded
before it: a step is written inside :func:`superex_deploy.parallel.signals_deferred`, so a signal never cuts one in
half. A process killed outright (SIGKILL, or SIGTERM with no handler) leaves ``PATH.part``, cut anywhere.
:func:`read_recording` reads the messages in order and stops at the first broken one (a truncated file), saying
which, and keeps every complete step before it.

Time stamps are those of :class:`~superex_deploy.messages.Observation` (finite, in ``[0, 2**31 - 1]`` s), so every
one fits the ``int32`` seconds of a ROS 2 time; yaws are already normalised to ``(-pi, pi]`` there.
"""

from __future__ import annotations

from superex_deploy.recording.reader import RecordedStep, Recording, read_recording
from superex_deploy.recording.schemas import (EXPLORER_COMMAND_MSG, FORMAT_VERSION, METADATA_TYPES, SPAD_FRAME_MSG,
                                             check_metadata)
from superex_deploy.recording.writer import EpisodeRecorder

__all__ = ["FORMAT_VERSION", "SPAD_FRAME_MSG", "EXPLORER_COMMAND_MSG", "METADATA_TYPES", "EpisodeRecorder",
           "RecordedStep", "Recording", "read_recording", "check_metadata"]

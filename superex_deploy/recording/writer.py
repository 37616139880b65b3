"""Writing an episode to MCAP: :class:`EpisodeRecorder` (atomic: a recording is complete, cut at a whole step
by a signal, or absent)."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Optional, Union

import numpy as np

from superex_deploy.messages import Command, MapFrame, Observation, check_stamp
from superex_deploy.parallel import signals_deferred
from superex_deploy.recording.schemas import (COVARIANCE_INDEX, FORMAT_VERSION, METADATA_NAME, SCHEMAS, check_metadata,
                                             header_message, pose_message, stamp_message)

__all__ = ["EpisodeRecorder"]


class EpisodeRecorder:
    """Writes an episode to ``path`` (see the module docstring); use as a context manager.

    Args:
        path: the ``.mcap`` file to write (its folder must exist; an existing file is replaced at the end).
        frame: the explorer's map frame.
        metadata: what a replay needs (JSON-serialisable values; see :func:`superex_deploy.commands.replay`).
        map_every: write the explorer's map every this many steps (and at the last step).
        chunk_bytes: messages are compressed in chunks of about this size; a file cut short (a crash, a full
            disk) loses at most its last chunk.

    Leaving the ``with`` block normally, or by ``KeyboardInterrupt`` (a signal), closes the file (:meth:`close`);
    by any other exception drops it (:meth:`abort`).

    Attributes:
        steps_written: the steps recorded so far (whole: a signal never cuts a step in half).

    Raises:
        ValueError: a path whose folder does not exist or that names a folder, a bad ``map_every``.
    """

    def __init__(self, path: Union[str, Path], frame: MapFrame, metadata: dict, map_every: int = 25,
                 chunk_bytes: int = 256 * 1024):
        from mcap_ros2.writer import Writer

        self.path = Path(path)
        if self.path.is_dir():
            raise ValueError(f"--record {self.path} is a folder, not a file")
        if not self.path.parent.is_dir():
            raise ValueError(f"--record {self.path}: the folder {self.path.parent} does not exist")
        if int(map_every) < 1:
            raise ValueError(f"map_every must be >= 1, got {map_every}")
        self.frame, self.map_every = frame, int(map_every)
        values = check_metadata({"format_version": FORMAT_VERSION,
                                 "frame": {"shape": list(frame.shape), "resolution_m": frame.resolution_m,
                                           "origin_xy": list(frame.origin_xy)}, **metadata}, f"--record {path}")
        try:
            encoded = {key: json.dumps(value) for key, value in values.items()}
        except TypeError as error:
            raise ValueError(f"recording metadata must be JSON-serialisable: {error}") from None
        self._part = self.path.with_name(self.path.name + ".part")
        self._file = None
        self._closed = False
        self.steps_written = 0
        self._last_map_step = -1
        self._last = (0.0, 0)
        try:  # a signal may arrive anywhere in here: nothing is left behind then
            self._file = open(self._part, "wb")
            self._writer = Writer(self._file, chunk_size=int(chunk_bytes))
            self._schemas = {topic: self._writer.register_msgdef(name, text)
                             for topic, (name, text) in SCHEMAS.items()}
            self._writer.add_metadata(METADATA_NAME, encoded)
        except BaseException:
            self.abort()
            raise

    def _write(self, topic: str, message: dict, stamp_s: float, step: int) -> None:
        nanoseconds = int(round(stamp_s * 1e9))
        self._writer.write_message(topic, self._schemas[topic], message, log_time=nanoseconds,
                                   publish_time=nanoseconds, sequence=step)

    def write(self, observation: Observation, command: Command, observed: Optional[np.ndarray] = None,
              frame: Optional[MapFrame] = None) -> None:
        """Record one step: the observation, the command and, every ``map_every`` steps, ``observed`` (int8
        ``[H, W]``, the explorer's map after the step) on ``frame`` (the explorer's frame of that step, which a
        map that grows changes; default: the recording's). A signal arriving meanwhile is handled after the step
        is whole.

        Raises:
            ValueError: ``observed`` is not of ``frame``'s shape (nothing of the step is written).
        """
        frame = self._frame_of(observed, frame)
        with signals_deferred():
            self._write_step(observation, command, observed, frame)
            self.steps_written += 1

    def _frame_of(self, observed: Optional[np.ndarray], frame: Optional[MapFrame]) -> MapFrame:
        frame = self.frame if frame is None else frame
        if observed is not None and np.shape(observed) != tuple(frame.shape):
            raise ValueError(f"the map to record has shape {np.shape(observed)}, its frame {tuple(frame.shape)} (a "
                             f"map that grows: pass the explorer's frame of the step)")
        return frame

    def _write_step(self, observation: Observation, command: Command, observed: Optional[np.ndarray],
                    frame: MapFrame) -> None:
        stamp, step = observation.stamp_s, command.step
        self._last = (stamp, step)
        pose = observation.pose
        self._write("/pose", {"header": header_message(stamp, "map"), "pose": pose_message(pose.x, pose.y, pose.yaw)},
                    stamp, step)
        scan = observation.scan
        if scan is not None:
            self._write("/scan", {"header": header_message(stamp, "base_scan"), "angle_min": scan.angle_min,
                                  "angle_max": scan.angle_max, "angle_increment": scan.angle_increment,
                                  "time_increment": 0.0, "scan_time": 0.0, "range_min": scan.range_min,
                                  "range_max": scan.range_max, "ranges": scan.ranges.tolist(), "intensities": []},
                        stamp, step)
        self._write_robot_inputs(observation, stamp, step)
        spad = observation.spad
        if spad is not None:
            self._write("/spad", {"header": header_message(stamp, "base_scan"), "bin_width_s": spad.bin_width_s,
                                  "n_rays": spad.n_rays, "n_bins": spad.n_bins, "nnz": int(spad.bins.size),
                                  "angles_f64le": spad.angles.astype("<f8").tobytes(),
                                  "row_start_i64le": spad.row_start.astype("<i8").tobytes(),
                                  "bins_i32le": spad.bins.astype("<i4").tobytes(),
                                  "counts_f32le": spad.counts.astype("<f4").tobytes()}, stamp, step)
        goal = command.goal_rc
        self._write("/command", {"header": header_message(stamp, "map"), "step": step, "has_goal": goal is not None,
                                 "goal_row": -1 if goal is None else goal[0],
                                 "goal_col": -1 if goal is None else goal[1],
                                 "goal_x": math.nan if goal is None else command.goal_xy[0],
                                 "goal_y": math.nan if goal is None else command.goal_xy[1],
                                 "new_goal": bool(command.new_goal), "finished": bool(command.finished),
                                 "prediction_step": int(command.prediction_step), "robot_yaw": pose.yaw,
                                 "prediction_age_s": (math.nan if command.prediction_age_s is None
                                                      else float(command.prediction_age_s)),
                                 "status": str(command.status), "reason": str(command.reason)},
                    stamp, step)
        self._write("/plan", {"header": header_message(stamp, "map"),
                              "poses": [{"header": header_message(stamp, "map"),
                                         "pose": pose_message(float(x), float(y), 0.0)}
                                        for x, y in command.path_xy]}, stamp, step)
        if observed is not None and (step % self.map_every == 0 or command.finished):
            self._write_map(observed, stamp, step, frame)

    def _write_robot_inputs(self, observation: Observation, stamp: float, step: int) -> None:
        """The SLAM map and the pose covariance of an observation that carries them."""
        grid = observation.occupancy_grid
        if grid is not None:
            self._write("/slam_map", {"header": header_message(stamp, "map"),
                                      "info": {"map_load_time": stamp_message(0.0), "resolution": grid.resolution_m,
                                               "width": grid.width, "height": grid.height,
                                               "origin": pose_message(grid.origin_xy[0], grid.origin_xy[1], 0.0)},
                                      "data": grid.data.tolist()}, stamp, step)
        covariance = observation.pose_covariance
        if covariance is not None:
            full = np.zeros((6, 6))
            full[np.ix_(COVARIANCE_INDEX, COVARIANCE_INDEX)] = covariance.matrix
            pose = observation.pose
            self._write("/pose_covariance", {"header": header_message(stamp, "map"),
                                             "pose": {"pose": pose_message(pose.x, pose.y, pose.yaw),
                                                      "covariance": full.ravel().tolist()}}, stamp, step)

    def write_map(self, observed: np.ndarray, stamp_s: Optional[float] = None, step: Optional[int] = None,
                  frame: Optional[MapFrame] = None) -> None:
        """Record the explorer's int8 ``[H, W]`` map (rows flipped: ROS grids start at the bottom row) on ``frame``
        (default: the recording's), stamped with the last recorded step unless told otherwise (once per step at
        most).

        Raises:
            ValueError: ``observed`` is not of ``frame``'s shape.
        """
        frame = self._frame_of(observed, frame)
        with signals_deferred():
            self._write_map(observed, stamp_s, step, frame)

    def _write_map(self, observed: np.ndarray, stamp_s: Optional[float], step: Optional[int],
                   frame: MapFrame) -> None:
        if stamp_s is None or step is None:
            stamp_s, step = self._last
        stamp_s = check_stamp("stamp_s", stamp_s)
        if step == self._last_map_step:
            return
        observed = np.asarray(observed)
        data = np.where(observed > 0, 100, observed).astype(np.int8)[::-1]
        height, width = frame.shape
        self._write("/map", {"header": header_message(stamp_s, "map"),
                             "info": {"map_load_time": stamp_message(0.0), "resolution": frame.resolution_m,
                                      "width": width, "height": height,
                                      "origin": pose_message(frame.origin_xy[0], frame.origin_xy[1], 0.0)},
                             "data": data.ravel().tolist()}, stamp_s, step)
        self._last_map_step = step

    def close(self) -> None:
        """Finish the file with the steps written so far and move it into place (on failure, nothing is left at
        ``path`` or ``path.part``); a signal arriving meanwhile is handled after it."""
        if self._closed:
            return
        with signals_deferred():
            try:
                self._writer.finish()
                self._file.close()
                os.replace(self._part, self.path)
            except BaseException:
                self.abort()
                raise
            self._closed = True

    def abort(self) -> None:
        """Drop the partial file (nothing is left at ``path``)."""
        if self._closed:
            return
        with signals_deferred():
            if self._file is not None:
                self._file.close()
            self._part.unlink(missing_ok=True)
            self._closed = True

    def __enter__(self) -> "EpisodeRecorder":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None or issubclass(exc_type, KeyboardInterrupt):
            self.close()
        else:
            self.abort()

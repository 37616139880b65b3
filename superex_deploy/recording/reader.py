"""Reading a recording back: :func:`read_recording` returns a :class:`Recording` of :class:`RecordedStep` objects, the
observations exactly as the explorer saw them; a damaged file keeps its whole steps and says where it broke."""

from __future__ import annotations

import io
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Union

import numpy as np

from superex_deploy.messages import MapFrame, Observation, Pose2D, PoseCovariance
from superex_deploy.messages.ros_fields import laser_scan, occupancy_grid, spad_frame
from superex_deploy.recording.schemas import (FORMAT_VERSION, METADATA_NAME, REPLAYED_TOPICS, check_metadata,
                                             stamp_seconds)

__all__ = ["RecordedStep", "Recording", "read_recording", "read_metadata", "check_format"]


@dataclass
class RecordedStep:
    """One step of a recording.

    Attributes:
        step: the explorer's step counter.
        observation: what the explorer received.
        goal_rc: the recorded command's goal cell, or None.
        new_goal, finished: the recorded command's flags.
        prediction_step: the step whose map the command's prediction was made from, -1 for none.
        prediction_age_s: the command's ``prediction_age_s``, or None (no prediction, or a file written before
            the field existed).
        status, reason: the command's ``status`` and ``reason``, or None (a file written before the fields
            existed).
    """

    step: int
    observation: Observation
    goal_rc: Optional[tuple[int, int]]
    new_goal: bool
    finished: bool
    prediction_step: int = -1
    prediction_age_s: Optional[float] = None
    status: Optional[str] = None
    reason: Optional[str] = None


@dataclass
class Recording:
    """What :func:`read_recording` read.

    Attributes:
        metadata: the ``superex.episode`` record, JSON values decoded.
        frame: the explorer's map frame.
        steps: the complete steps, in order.
        error: None, or what stopped the reading (the broken message and why).
    """

    metadata: dict
    frame: MapFrame
    steps: list = field(default_factory=list)
    error: Optional[str] = None


def _observation(parts: dict, frame: MapFrame) -> Observation:
    pose_message, scan_message = parts["/pose"], parts.get("/scan")
    yaw = float(parts["/command"].robot_yaw)
    pose = Pose2D(pose_message.pose.position.x, pose_message.pose.position.y, yaw)
    scan = None if scan_message is None else laser_scan(scan_message)
    spad = spad_frame(parts["/spad"]) if "/spad" in parts else None
    # The SLAM map's header holds the map's own stamp: a map handed to several steps replays as one map.
    grid = occupancy_grid(parts["/slam_map"], frame.resolution_m) if "/slam_map" in parts else None
    covariance = None
    if "/pose_covariance" in parts:
        covariance = PoseCovariance.from_ros(np.asarray(parts["/pose_covariance"].pose.covariance, np.float64))
    return Observation(stamp_s=stamp_seconds(pose_message.header.stamp), pose=pose, scan=scan, spad=spad,
                       pose_covariance=covariance, occupancy_grid=grid)


def _metadata(data: bytes, path: Path) -> dict:
    from mcap.reader import NonSeekingReader

    reader = NonSeekingReader(io.BytesIO(data))
    try:
        for record in reader.iter_metadata():
            if record.name == METADATA_NAME:
                try:
                    metadata = {key: json.loads(value) for key, value in record.metadata.items()}
                except json.JSONDecodeError as error:
                    raise ValueError(f"{path}: the {METADATA_NAME!r} metadata is not JSON ({error})") from None
                return check_metadata(metadata, str(path))
    except ValueError:
        raise
    except Exception:  # the metadata comes first: a file broken before it holds nothing usable
        pass
    raise ValueError(f"{path} is not a SuperEx recording: no readable {METADATA_NAME!r} metadata record")


def check_format(metadata: dict, path: Path) -> None:
    """Refuse a recording whose metadata gives another format than :data:`FORMAT_VERSION`: an older one (the
    error names ``superex convert-recording``, which rewrites it) or a newer one (upgrade).

    Raises:
        ValueError: another format version, said in one line.
    """
    version = metadata.get("format_version")
    if version == FORMAT_VERSION:
        return
    known = isinstance(version, str) and version.isdigit()
    why = ""
    if known and int(version) > int(FORMAT_VERSION):
        why = ": a newer version of superex_deploy wrote it; upgrade to replay it"
    elif known:
        why = (f": an older version of superex_deploy wrote it; convert it with `superex convert-recording {path} "
               f"NEW.mcap` and replay NEW.mcap")
    raise ValueError(f"{path} has recording format {version!r}, this package reads {FORMAT_VERSION!r}{why}")


def read_metadata(path: Union[str, Path]) -> dict:
    """The ``superex.episode`` metadata of the recording ``path`` (JSON values decoded, types checked), of any
    format version: what ``superex convert-recording`` reads.

    Raises:
        ValueError: a missing file, or a file that is not an MCAP recording with SuperEx metadata.
    """
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"recording {path} does not exist or is not a file")
    return _metadata(path.read_bytes(), path)


def _message_count(data: bytes) -> Optional[int]:
    """The number of messages the file's summary section states, or None (no summary: a cut file)."""
    from mcap.reader import make_reader

    try:
        summary = make_reader(io.BytesIO(data)).get_summary()
        return None if summary is None or summary.statistics is None else int(summary.statistics.message_count)
    except Exception:  # noqa: BLE001 - a broken summary only costs the progress bar its total
        return None


def read_recording(path: Union[str, Path], progress: bool = False) -> Recording:
    """Read a recording written by :class:`EpisodeRecorder`.

    Reading stops at the first message that cannot be decoded or is inconsistent (a truncated file, a corrupt
    record); :attr:`Recording.error` then names it (a file that ends inside a record is said to be truncated, at
    its size in bytes), and :attr:`Recording.steps` holds every complete step before it.

    Args:
        path: the ``.mcap`` file.
        progress: show a progress bar (tqdm, on stderr) over the messages read, from the first one.

    Raises:
        ValueError: a missing file, a file that is not an MCAP recording with SuperEx metadata, metadata values of
            the wrong type (:data:`METADATA_TYPES`), another format version (:func:`check_format`), a map frame
            beyond the size limits (:func:`superex_deploy.messages.check_map_size`).
    """
    from mcap.exceptions import EndOfFile
    from mcap.reader import NonSeekingReader
    from mcap_ros2.decoder import DecoderFactory
    from tqdm import tqdm

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"recording {path} does not exist or is not a file")
    data = path.read_bytes()
    metadata = _metadata(data, path)
    check_format(metadata, path)
    try:
        frame_fields = metadata["frame"]
        frame = MapFrame(tuple(frame_fields["shape"]), frame_fields["resolution_m"], tuple(frame_fields["origin_xy"]))
    except (KeyError, TypeError, ValueError) as error:
        raise ValueError(f"{path}: the map frame in the metadata is unusable ({error})") from None
    recording = Recording(metadata=metadata, frame=frame)
    stream = io.BytesIO(data)
    reader = NonSeekingReader(stream, validate_crcs=True, decoder_factories=[DecoderFactory()])
    parts: dict = {}
    current = -1
    done = 0  # messages fully read
    topic, sequence = "?", -1
    # In file order: sorting by time would read the whole file before yielding, and a cut one not at all.
    with tqdm(reader.iter_decoded_messages(log_time_order=False), desc=f"reading {path.name}", unit="msg",
              total=_message_count(data) if progress else None, disable=not progress) as messages:
        try:
            for _, channel, message, decoded in messages:
                topic, sequence = channel.topic, message.sequence
                if topic in REPLAYED_TOPICS:
                    if sequence != current:
                        parts, current = {}, sequence
                    parts[topic] = decoded
                    if topic == "/command":
                        if "/pose" not in parts or ("/scan" not in parts and "/slam_map" not in parts):
                            raise ValueError("a command without the pose and scan (or SLAM map) of its step")
                        goal = (int(decoded.goal_row), int(decoded.goal_col)) if decoded.has_goal else None
                        recording.steps.append(RecordedStep(step=int(decoded.step),
                                                            observation=_observation(parts, frame),
                                                            goal_rc=goal, new_goal=bool(decoded.new_goal),
                                                            finished=bool(decoded.finished),
                                                            prediction_step=int(decoded.prediction_step),
                                                            prediction_age_s=_age(decoded),
                                                            status=getattr(decoded, "status", None),
                                                            reason=getattr(decoded, "reason", None)))
                done += 1
                topic, sequence = "?", -1
        except Exception as error:  # noqa: BLE001 - any decoding failure ends the readable part
            steps = recording.steps
            if topic != "?":
                where = f"topic {topic}, step {sequence}"
            else:
                where = f"after step {steps[-1].step}" if steps else "before the first step"
            if isinstance(error, EndOfFile) or stream.tell() >= len(data):
                why = f"the file is truncated: it ends at byte {len(data):,}, inside a record"
            else:
                why = f"{type(error).__name__}: {error}" if str(error) else type(error).__name__
            recording.error = f"message {done + 1} ({where}) is broken: {why}; kept the {len(steps)} complete " \
                              f"steps before it"
    return recording


def _age(decoded) -> Optional[float]:
    """A command's ``prediction_age_s``: None for NaN (no prediction) and for files written before the field."""
    age = float(getattr(decoded, "prediction_age_s", math.nan))
    return None if math.isnan(age) else age

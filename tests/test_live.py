"""The live view (``--live``): every channel of an episode served on a Foxglove WebSocket, from the recording's
channel table; a busy port and a missing extra each one clear error; the server stopped (its port free) however the
run ends."""

import json
import os
import signal
import socket
import struct
import sys
import threading
import time

import numpy as np
import pytest

from superex_deploy.maps import load_map, start_poses
from superex_deploy.messages import MapFrame
from superex_deploy.recording.channels import (CHANNELS, MESSAGE_ENCODING, RECORDED_CHANNELS, SCHEMA_ENCODING,
                                               StepData, channel, map_message, plain_values)
from superex_deploy.recording.live import (MISSING_EXTRA, LiveServer, busy_port_message, encode, live_view,
                                           parse_address)
from superex_deploy.recording.schemas import SCHEMAS

MAP = "50052750"
SUBPROTOCOL = "foxglove.sdk.v1"  # the foxglove-sdk server's protocol (the messages of foxglove.websocket.v1)
MESSAGE_DATA = 1  # opcode of a binary server frame of message data


def _threads() -> set:
    """The running threads, but tqdm's monitor (started by the first progress bar, left for the process); a run
    leaves none behind when the threads after it are among those before (a client thread of an earlier test may end
    meanwhile)."""
    return {thread for thread in threading.enumerate() if not thread.name.startswith("tqdm_monitor")}


def _free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def _port_is_free(port: int) -> bool:
    """Whether a new server could listen on ``port`` (as servers bind: ``SO_REUSEADDR``)."""
    with socket.socket() as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            probe.bind(("127.0.0.1", port))
        except OSError:
            return False
        return True


def _decoder(spec):
    from mcap.records import Schema
    from mcap_ros2.decoder import DecoderFactory

    return DecoderFactory().decoder_for(MESSAGE_ENCODING, Schema(id=1, name=spec.type_name, encoding=SCHEMA_ENCODING,
                                                                 data=spec.schema.encode()))


def test_the_recorded_channels_are_the_recordings_schemas_and_each_topic_is_one_channel():
    assert [spec.topic for spec in RECORDED_CHANNELS] == ["/pose", "/scan", "/slam_map", "/pose_covariance", "/spad",
                                                          "/command", "/plan", "/map"]
    assert {spec.topic: (spec.type_name, spec.schema) for spec in RECORDED_CHANNELS} == SCHEMAS
    assert len({spec.topic for spec in CHANNELS}) == len(CHANNELS)
    live_only = {spec.topic: spec.type_name for spec in CHANNELS if not spec.recorded}
    assert live_only == {"/tf": "tf2_msgs/msg/TFMessage", "/goal": "geometry_msgs/msg/PoseStamped",
                         "/prediction": "nav_msgs/msg/OccupancyGrid", "/evidence": "nav_msgs/msg/OccupancyGrid"}
    with pytest.raises(KeyError, match="/nope"):
        channel("/nope")


def _encoder(spec):
    from mcap_ros2._dynamic import serialize_dynamic

    return serialize_dynamic(spec.type_name, spec.schema)[spec.type_name]


def _step(path_xy, ranges, stamp_s=12.345):
    from superex_deploy.messages import Command, LaserScan, Observation, OccupancyGridMessage, Pose2D, PoseCovariance

    scan = None if ranges is None else LaserScan(-1.0, 2.0 / max(len(ranges) - 1, 1), 0.1, 5.0, ranges)
    slam = None if scan is not None else OccupancyGridMessage(0.1, 5, 7, (0.0, 0.0), np.arange(35, dtype=np.int8))
    path = np.asarray(path_xy, np.float64).reshape(-1, 2)
    goal = (tuple(path[-1]), (1, 2)) if len(path) else (None, None)
    command = Command(stamp_s, goal[0], goal[1], path, np.zeros((len(path), 2), np.int64), False, False)
    observation = Observation(stamp_s, Pose2D(1.0, 2.0, 0.5), scan, occupancy_grid=slam,
                              pose_covariance=PoseCovariance(np.diag([0.1, 0.2, 0.3])))
    return StepData(observation, command, MapFrame((7, 5), 0.1), observed=np.zeros((7, 5), np.int8),
                    prediction=np.full((7, 5), 0.25, np.float32), evidence=np.eye(7, 5, dtype=np.float32))


@pytest.mark.parametrize("stamp_s", [0.0, 12.345, 2.0 ** 31 - 1])
def test_the_live_bytes_of_every_channel_are_the_mcap_writers_encoders(stamp_s):
    observed = np.random.default_rng(0).integers(-1, 2, (7, 5)).astype(np.int8)
    grid_spec = channel("/map")
    for frame in (MapFrame((7, 5), 0.1, (0.5, -1.25)), MapFrame((7, 5), 0.05), MapFrame((1, 1), 0.1)):
        message = map_message(observed[:frame.shape[0], :frame.shape[1]], frame, stamp_s)
        assert encode(grid_spec, message, _encoder(grid_spec)) == _encoder(grid_spec)(plain_values(message))
    rng = np.random.default_rng(1)
    for n in (0, 1, 2, 3, 17):
        for ranges in (None, rng.uniform(0.1, 5.0, max(n, 1)).astype(np.float32), np.array([np.inf, np.nan, 1e-3])):
            step = _step(rng.uniform(-50, 50, (n, 2)), ranges, stamp_s)
            for spec in CHANNELS:
                message = spec.build(step)
                if message is not None:
                    assert encode(spec, message, _encoder(spec)) == _encoder(spec)(plain_values(message)), spec.topic
    odd = {"header": {"stamp": {"sec": 1, "nanosec": 2}, "frame_id": "odd"},  # poses of their own headers
           "poses": [{"header": {"stamp": {"sec": 1, "nanosec": k}, "frame_id": "map" * k},
                      "pose": {"position": {"x": 1.0, "y": 2.0, "z": 3.0},
                               "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}}} for k in range(3)]}
    assert encode(channel("/plan"), odd, _encoder(channel("/plan"))) == _encoder(channel("/plan"))(odd)
    for top, shared in [(top, shared) for top in ("", "ab", "map", "odom0") for shared in ("", "a", "abcd", "abcde")]:
        header = {"stamp": {"sec": 7, "nanosec": 9}, "frame_id": shared}  # every alignment of the poses' layout
        path = {"header": {"stamp": {"sec": 7, "nanosec": 9}, "frame_id": top},
                "poses": [{"header": header, "pose": {"position": {"x": x, "y": -x, "z": 0.5},
                                                      "orientation": {"x": 0.0, "y": 0.1, "z": 0.2, "w": 0.9}}}
                          for x in (1.0, 2.5, -3.25)]}
        assert encode(channel("/plan"), path, _encoder(channel("/plan"))) == _encoder(channel("/plan"))(path)


@pytest.mark.parametrize("text, address", [("127.0.0.1:8765", ("127.0.0.1", 8765)), ("0.0.0.0:0", ("0.0.0.0", 0)),
                                           ("[::1]:9000", ("::1", 9000)), ("localhost:65535", ("localhost", 65535))])
def test_an_address_is_host_and_port(text, address):
    assert parse_address(text) == address


@pytest.mark.parametrize("text", ["8765", ":8765", "host:", "host:x", "host:70000", "host:-1"])
def test_a_bad_address_is_refused(text):
    with pytest.raises(ValueError, match="HOST:PORT"):
        parse_address(text)


@pytest.mark.parametrize("argv, option", [(["--live", "8765"], "--live"), (["--live", "host:port"], "--live"),
                                          (["--live", "--live-every", "-1"], "--live-every"),
                                          (["--live-every", "nan"], "--live-every")])
def test_a_bad_live_option_is_refused_naming_it_before_anything_is_created(tmp_path, capsys, argv, option):
    from superex_deploy.cli import main

    out = tmp_path / "out"
    assert main(["explore", "--map", MAP] + argv + ["--out", str(out)]) == 2
    assert f"argument {option}:" in capsys.readouterr().err and not out.exists()


def test_live_takes_its_default_address_without_one():
    from superex_deploy.cli import build_parser

    args = build_parser().parse_args(["explore", "--map", MAP, "--live", "--out", "x"])
    assert (args.live, args.live_every) == (("127.0.0.1", 8765), 0.5)
    args = build_parser().parse_args(["replay", "r.mcap", "--live", "0.0.0.0:0", "--live-every", "2", "--out", "x"])
    assert (args.live, args.live_every) == (("0.0.0.0", 0), 2.0)
    assert build_parser().parse_args(["explore", "--map", MAP, "--out", "x"]).live is None


def test_live_without_the_extra_is_one_clear_error(monkeypatch, tmp_path, capsys):
    from superex_deploy.cli import main

    monkeypatch.setitem(sys.modules, "foxglove", None)  # `import foxglove` raises ImportError
    with pytest.raises(ValueError) as refused:
        LiveServer(port=0)
    assert str(refused.value) == MISSING_EXTRA == ("--live needs the foxglove-sdk package, which is not installed: "
                                                   "pip install 'superex[live]'")
    out = tmp_path / "out"
    assert main(["explore", "--map", MAP, "--steps", "2", "--live", "--out", str(out)]) == 2
    assert capsys.readouterr().err.strip() == f"superex explore: error: {MISSING_EXTRA}"
    assert not out.exists()


def test_a_busy_port_is_one_clear_error_naming_it(tmp_path, capsys):
    pytest.importorskip("foxglove")
    from superex_deploy.cli import main

    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        with pytest.raises(ValueError) as refused:
            LiveServer("127.0.0.1", port)
        assert str(refused.value) == busy_port_message("127.0.0.1", port)
        assert f"127.0.0.1:{port}" in str(refused.value) and "already in use" in str(refused.value)
        out = tmp_path / "out"
        assert main(["explore", "--map", MAP, "--steps", "2", "--live", f"127.0.0.1:{port}", "--out", str(out)]) == 2
        assert capsys.readouterr().err.strip() == f"superex explore: error: {busy_port_message('127.0.0.1', port)}"
        assert not out.exists()


def test_the_server_is_stopped_and_its_port_free_however_the_block_ends():
    pytest.importorskip("foxglove")
    threads = _threads()
    port = _free_port()
    with live_view(("127.0.0.1", port), 0.5) as server:
        assert not _port_is_free(port) and server.port == port
    assert server.closed and _port_is_free(port)
    for stop in (KeyboardInterrupt, RuntimeError):
        with pytest.raises(stop):
            with live_view(("127.0.0.1", port), 0.5):
                raise stop()
        assert _port_is_free(port)
    server.close()  # idempotent
    with pytest.raises(RuntimeError, match="closed"):
        server.publish(None, None, None)
    assert _threads() <= threads
    with live_view(None, 0.5) as nothing:
        assert nothing is None


def test_explore_and_replay_live_run_as_without_it_and_free_the_port(tmp_path, capsys):
    pytest.importorskip("foxglove")
    from superex_deploy.cli import main

    port = _free_port()
    threads = _threads()
    common = ["explore", "--map", MAP, "--steps", "4", "--gif-every", "0", "--profile", "full"]  # deterministic
    assert main(common + ["--out", str(tmp_path / "plain"), "--record", str(tmp_path / "plain.mcap")]) == 0
    assert main(common + ["--live", f"127.0.0.1:{port}", "--live-every", "0", "--out", str(tmp_path / "live"),
                          "--record", str(tmp_path / "live.mcap")]) == 0
    assert f"superex explore: live view on ws://127.0.0.1:{port}" in capsys.readouterr().err
    assert _port_is_free(port) and _threads() <= threads
    # The live view changes nothing of the run: the same recording, byte for byte, and the same episode.
    assert (tmp_path / "live.mcap").read_bytes() == (tmp_path / "plain.mcap").read_bytes()
    plain, live = (json.loads((tmp_path / name / "metrics.json").read_text()) for name in ("plain", "live"))
    episode = ("coverage", "poses", "goals")
    assert [live[key] for key in episode] == [plain[key] for key in episode]
    assert main(["replay", str(tmp_path / "live.mcap"), "--live", f"127.0.0.1:{port}", "--out",
                 str(tmp_path / "replay")]) == 0
    assert f"superex replay: live view on ws://127.0.0.1:{port}" in capsys.readouterr().err
    assert _port_is_free(port) and _threads() <= threads


def _receive(ws, deadline: float):
    """The next frame (text as a dict, binary as bytes), or None at the deadline."""
    try:
        frame = ws.recv(timeout=max(0.01, deadline - time.monotonic()))
    except TimeoutError:
        return None
    return json.loads(frame) if isinstance(frame, str) else frame


def test_an_episode_is_served_on_every_channel_and_each_message_decodes():
    pytest.importorskip("foxglove")
    websockets_client = pytest.importorskip("websockets.sync.client")
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.pipeline import make_predictor, make_sensing
    from superex_deploy.sim.episode import run_episode

    grid = load_map(MAP)
    explorers, observations = [], []
    with LiveServer("127.0.0.1", 0, every_s=0.0) as server, \
            websockets_client.connect(server.url, subprotocols=[SUBPROTOCOL], max_size=None, max_queue=None) as ws:
        deadline = time.monotonic() + 10
        info = _receive(ws, deadline)
        assert info["op"] == "serverInfo" and info["name"] == "superex"
        advertised = {}
        while len(advertised) < len(CHANNELS):
            frame = _receive(ws, deadline)
            assert frame is not None, f"advertised only {sorted(advertised)}"
            if isinstance(frame, dict) and frame["op"] == "advertise":
                advertised.update({item["topic"]: item for item in frame["channels"]})
        for spec in CHANNELS:
            item = advertised[spec.topic]
            assert (item["schemaName"], item["schemaEncoding"], item["encoding"], item["schema"]) == \
                (spec.type_name, SCHEMA_ENCODING, MESSAGE_ENCODING, spec.schema)
        assert advertised["/map"]["schemaName"] == advertised["/prediction"]["schemaName"] == \
            advertised["/evidence"]["schemaName"] == "nav_msgs/msg/OccupancyGrid"
        subscriptions = {index: topic for index, topic in enumerate(sorted(advertised), start=10)}
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [
            {"id": index, "channelId": advertised[topic]["id"]} for index, topic in subscriptions.items()]}))
        while set(server.subscribed_topics()) != set(advertised) and time.monotonic() < deadline:
            time.sleep(0.01)

        def publish(observation, command, explorer):
            explorers.append(explorer)
            observations.append(observation)
            server.publish(observation, command, explorer)

        run_episode(grid, start_poses(MAP)[0], make_planner("superex"), make_predictor("evidence", grid),
                             steps=8, sensing=make_sensing("evidence", True, 0), on_observation=publish)
        received, count = {}, 0
        deadline = time.monotonic() + 20
        while count < sum(server.published.values()) and time.monotonic() < deadline:
            frame = _receive(ws, deadline)
            if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                subscription, stamp_ns = struct.unpack_from("<IQ", frame, 1)
                received.setdefault(subscriptions[subscription], []).append((stamp_ns, frame[13:]))
                count += 1
    explorer = explorers[-1]
    assert server.closed
    assert set(received) >= {"/map", "/scan", "/pose", "/plan", "/goal", "/prediction", "/evidence", "/tf",
                             "/command", "/spad"}, f"received only {sorted(received)}"
    assert {topic: len(messages) for topic, messages in received.items()} == \
        {topic: count for topic, count in server.published.items() if count}, "every message published arrived"
    assert server.published["/pose"] == 8
    decoded = {topic: [_decoder(channel(topic))(payload) for _, payload in messages]
               for topic, messages in received.items()}
    height, width = explorer.frame.shape
    for topic in ("/map", "/prediction", "/evidence"):
        for grid_msg in decoded[topic]:
            assert (grid_msg.info.width, grid_msg.info.height) == (width, height), topic
            assert grid_msg.header.frame_id == "map" and len(grid_msg.data) == width * height
    final_map = np.asarray(decoded["/map"][-1].data, np.int8).reshape(height, width)[::-1]
    assert np.array_equal(final_map, np.where(explorer.observed > 0, 100, explorer.observed))
    assert set(np.unique(final_map)) <= {-1, 0, 100}
    prediction = np.asarray(decoded["/prediction"][-1].data)
    evidence = np.asarray(decoded["/evidence"][-1].data)
    assert prediction.min() >= 0 and prediction.max() <= 100 and evidence.min() >= 0 and evidence.max() <= 100
    assert evidence.max() > 0, "the SPAD evidence reached the live view"
    last_pose, observation = decoded["/pose"][-1], observations[-1]
    assert (last_pose.pose.position.x, last_pose.pose.position.y) == (observation.pose.x, observation.pose.y)
    assert last_pose.header.frame_id == "map"
    assert received["/pose"][-1][0] == round(7 * 0.1 * 1e9)  # stamped with the observation's (simulated) time
    assert decoded["/tf"][-1].transforms[0].child_frame_id == decoded["/scan"][-1].header.frame_id == "base_scan"
    assert len(decoded["/scan"][-1].ranges) > 0
    assert [command.step for command in decoded["/command"]] == list(range(8))
    goal = decoded["/goal"][-1]
    assert goal.header.frame_id == "map" and np.isfinite(goal.pose.position.x)
    assert all(path.header.frame_id == "map" for path in decoded["/plan"])


def test_grids_are_published_at_most_once_per_every_s_of_simulated_time():
    pytest.importorskip("foxglove")
    websockets_client = pytest.importorskip("websockets.sync.client")
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
    from superex_deploy.sim.episode import run_episode

    grid = load_map(MAP)
    with LiveServer("127.0.0.1", 0, every_s=0.5) as server:
        assert server.subscribed_topics() == []
        run_episode(grid, start_poses(MAP)[0], make_planner("nearest"), ObservedAsPrediction(), steps=3,
                    on_observation=server.publish)
    assert set(server.published.values()) == {0}, "nothing is built for a topic nobody subscribes to"
    with LiveServer("127.0.0.1", 0, every_s=0.5) as server, \
            websockets_client.connect(server.url, subprotocols=[SUBPROTOCOL], max_queue=None) as ws:
        deadline = time.monotonic() + 10
        ids = {}
        while len(ids) < len(CHANNELS):
            frame = _receive(ws, deadline)
            assert frame is not None
            if isinstance(frame, dict) and frame["op"] == "advertise":
                ids.update({item["topic"]: item["id"] for item in frame["channels"]})
        ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": ids["/map"]},
                                                                 {"id": 2, "channelId": ids["/pose"]}]}))
        while len(server.subscribed_topics()) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert sorted(server.subscribed_topics()) == ["/map", "/pose"]
        run_episode(grid, start_poses(MAP)[0], make_planner("nearest"), ObservedAsPrediction(), steps=12,
                    on_observation=server.publish)
    # 12 steps of 0.1 s: the maps of 0.0, 0.5 and 1.0 s, every pose, nothing else.
    assert server.published["/pose"] == 12 and server.published["/map"] == 3
    assert sum(server.published.values()) == 15


@pytest.mark.parametrize("signum, code", [(signal.SIGINT, 130), (signal.SIGTERM, 143)], ids=["SIGINT", "SIGTERM"])
def test_a_live_run_stopped_by_a_signal_stops_its_server(tmp_path, capsys, monkeypatch, signum, code):
    pytest.importorskip("foxglove")
    from superex_deploy.cli import main
    from superex_deploy.onboard import Explorer

    step, at = Explorer.step, {"step": 3}

    def step_then_signal(self, observation):
        command = step(self, observation)
        if command.step == at["step"]:
            os.kill(os.getpid(), signum)
        return command

    monkeypatch.setattr(Explorer, "step", step_then_signal)
    port = _free_port()
    threads = _threads()
    record = tmp_path / "ep.mcap"
    assert main(["explore", "--map", MAP, "--steps", "50", "--gif-every", "0", "--live", f"127.0.0.1:{port}",
                 "--out", str(tmp_path / "run"), "--record", str(record)]) == code
    err = capsys.readouterr().err
    assert f"superex explore: stopped by {signal.Signals(signum).name}" in err and "holds the 3 whole steps" in err
    assert _port_is_free(port) and _threads() <= threads
    at["step"] = 1  # the recording holds 3
    assert main(["replay", str(record), "--live", f"127.0.0.1:{port}", "--out", str(tmp_path / "replay")]) == code
    assert _port_is_free(port) and _threads() <= threads

"""The live view (``--live``): every channel of an episode served on a Foxglove WebSocket, from the recording's
channel table; a busy port and a missing extra each one clear error; the server stopped (its port free) however the
run ends; a client that stops reading holds neither the episode nor the command's end (a real websocket client that
subscribes, then never reads again); the episode paced for a viewer (``--live-pace``) and its last state served after
it (``--live-hold``), which Ctrl-C ends."""

import json
import os
import queue
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from superex_deploy.maps import load_map, start_poses
from superex_deploy.messages import MapFrame
from superex_deploy.recording.channels import (CHANNELS, MESSAGE_ENCODING, RECORDED_CHANNELS, SCHEMA_ENCODING,
                                               StepData, channel, map_message, plain_values)
from superex_deploy.recording.live import (CLIENT_WAIT_S, DEFAULT_HOLD_S, MISSING_EXTRA, LiveServer,
                                           busy_port_message, encode, live_view, parse_address)
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
                                          (["--live-every", "nan"], "--live-every"),
                                          (["--live", "--live-pace", "-1"], "--live-pace"),
                                          (["--live-pace", "inf"], "--live-pace"),
                                          (["--live-pace", "fast"], "--live-pace"),
                                          (["--live", "--live-hold", "-0.5"], "--live-hold"),
                                          (["--live-hold", "nan"], "--live-hold")])
def test_a_bad_live_option_is_refused_naming_it_before_anything_is_created(tmp_path, capsys, argv, option):
    from superex_deploy.cli import main

    out = tmp_path / "out"
    assert main(["explore", "--map", MAP] + argv + ["--out", str(out)]) == 2
    assert f"argument {option}:" in capsys.readouterr().err and not out.exists()


def test_live_takes_its_default_address_without_one():
    from superex_deploy.cli import build_parser

    args = build_parser().parse_args(["explore", "--map", MAP, "--live", "--out", "x"])
    assert (args.live, args.live_every, args.live_pace, args.live_hold) == (("127.0.0.1", 8765), 0.5, None, 10.0)
    assert DEFAULT_HOLD_S == 10.0
    args = build_parser().parse_args(["replay", "r.mcap", "--live", "0.0.0.0:0", "--live-every", "2", "--live-pace",
                                      "0", "--live-hold", "2.5", "--out", "x"])
    assert (args.live, args.live_every, args.live_pace, args.live_hold) == (("0.0.0.0", 0), 2.0, 0.0, 2.5)
    assert build_parser().parse_args(["explore", "--map", MAP, "--out", "x"]).live is None


def test_live_without_the_extra_is_one_clear_error(monkeypatch, tmp_path, capsys):
    from superex_deploy.cli import main

    monkeypatch.setitem(sys.modules, "foxglove", None)  # `import foxglove` raises ImportError
    with pytest.raises(ValueError) as refused:
        LiveServer(port=0)
    assert str(refused.value) == MISSING_EXTRA == ("--live needs the foxglove-sdk package, which is not installed: "
                                                   "pip install 'superex[live]'")
    out = tmp_path / "out"
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "2", "--live", "--out", str(out)]) == 2
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
        assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "2", "--live", f"127.0.0.1:{port}",
                     "--out", str(out)]) == 2
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
    common = ["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "4", "--gif-every", "0", "--profile",
              "full"]  # deterministic
    assert main(common + ["--out", str(tmp_path / "plain"), "--record", str(tmp_path / "plain.mcap")]) == 0
    assert main(common + ["--live", f"127.0.0.1:{port}", "--live-every", "0", "--live-hold", "0", "--out",
                          str(tmp_path / "live"), "--record", str(tmp_path / "live.mcap")]) == 0
    assert f"superex explore: live view on ws://127.0.0.1:{port}" in capsys.readouterr().err
    assert _port_is_free(port) and _threads() <= threads
    # The live view changes nothing of the run: the same recording, byte for byte, and the same episode.
    assert (tmp_path / "live.mcap").read_bytes() == (tmp_path / "plain.mcap").read_bytes()
    plain, live = (json.loads((tmp_path / name / "metrics.json").read_text()) for name in ("plain", "live"))
    episode = ("coverage", "poses", "goals")
    assert [live[key] for key in episode] == [plain[key] for key in episode]
    assert main(["replay", str(tmp_path / "live.mcap"), "--live", f"127.0.0.1:{port}", "--live-hold", "0", "--out",
                 str(tmp_path / "replay")]) == 0
    assert f"superex replay: live view on ws://127.0.0.1:{port}" in capsys.readouterr().err
    assert _port_is_free(port) and _threads() <= threads



def _advertised(ws, deadline: float, topics) -> dict:
    """Topic -> channel id of the server's advertisements, read until ``topics`` are all advertised (fails at
    ``deadline``)."""
    ids = {}
    while not set(topics) <= set(ids):
        frame = _receive(ws, deadline)
        assert frame is not None
        if isinstance(frame, dict) and frame["op"] == "advertise":
            ids.update({item["topic"]: item["id"] for item in frame["channels"]})
    return ids


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
    from superex_deploy.pipeline import PROFILES, make_predictor, make_sensing
    from superex_deploy.evaluation.episodes import run_episode

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
                             steps=8, sensing=make_sensing("evidence", True, 0, profile=PROFILES["full"]),
                             on_observation=publish)
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
    from superex_deploy.evaluation.episodes import run_episode

    grid = load_map(MAP)
    with LiveServer("127.0.0.1", 0, every_s=0.5) as server:
        assert server.subscribed_topics() == []
        run_episode(grid, start_poses(MAP)[0], make_planner("nearest"), ObservedAsPrediction(), steps=3,
                    on_observation=server.publish)
    assert set(server.published.values()) == {0}, "nothing is built for a topic nobody subscribes to"
    with LiveServer("127.0.0.1", 0, every_s=0.5) as server, \
            websockets_client.connect(server.url, subprotocols=[SUBPROTOCOL], max_queue=None) as ws:
        deadline = time.monotonic() + 10
        ids = _advertised(ws, deadline, {spec.topic for spec in CHANNELS})
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
    assert main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "50", "--gif-every", "0", "--live",
                 f"127.0.0.1:{port}", "--out", str(tmp_path / "run"), "--record", str(record)]) == code
    err = capsys.readouterr().err
    assert f"superex explore: stopped by {signal.Signals(signum).name}" in err and "holds the 3 whole steps" in err
    assert _port_is_free(port) and _threads() <= threads
    at["step"] = 1  # the recording holds 3
    assert main(["replay", str(record), "--live", f"127.0.0.1:{port}", "--out", str(tmp_path / "replay")]) == code
    assert _port_is_free(port) and _threads() <= threads


# --- A client that stops reading -----------------------------------------------------------------------------------


def _stalled_client(host: str, port: int, topics=None) -> socket.socket:
    """A websocket client (``websockets``' own protocol, on a socket with a tiny receive buffer) that connects,
    subscribes to ``topics`` (None: every channel) and then never reads again: the socket it returns, for the test to
    close. Every wait has a timeout (10 s)."""
    from websockets.client import ClientProtocol
    from websockets.frames import Frame, Opcode
    from websockets.uri import parse_uri

    sock = socket.socket()
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1024)  # before connecting: a small window
    sock.settimeout(10)
    sock.connect((host, port))
    protocol = ClientProtocol(parse_uri(f"ws://{host}:{port}"), subprotocols=[SUBPROTOCOL], max_size=None)
    protocol.send_request(protocol.connect())
    sock.sendall(b"".join(protocol.data_to_send()))
    ids, deadline = {}, time.monotonic() + 10
    while len(ids) < len(CHANNELS):
        assert time.monotonic() < deadline, f"advertised only {sorted(ids)}"
        data = sock.recv(65536)
        assert data, "the server closed the connection"
        protocol.receive_data(data)
        for event in protocol.events_received():
            if isinstance(event, Frame) and event.opcode == Opcode.TEXT:
                message = json.loads(event.data)
                if message["op"] == "advertise":
                    ids.update({item["topic"]: item["id"] for item in message["channels"]})
    assert protocol.handshake_exc is None
    wanted = sorted(ids) if topics is None else topics
    protocol.send_text(json.dumps({"op": "subscribe", "subscriptions": [
        {"id": index, "channelId": ids[topic]} for index, topic in enumerate(wanted)]}).encode())
    sock.sendall(b"".join(protocol.data_to_send()))
    return sock


def test_a_client_that_stops_reading_holds_neither_the_episode_nor_the_stop():
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    from superex_deploy.onboard.planning.planners import make_planner
    from superex_deploy.onboard.prediction.baselines import ObservedAsPrediction
    from superex_deploy.evaluation.episodes import run_episode

    grid = load_map(MAP)
    threads = _threads()
    server = LiveServer("127.0.0.1", 0, every_s=0.0)
    client = _stalled_client("127.0.0.1", server.port)
    try:
        deadline = time.monotonic() + 10
        while len(server.subscribed_topics()) < len(CHANNELS) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert len(server.subscribed_topics()) == len(CHANNELS)
        publish_s = []

        def publish(observation, command, explorer):
            began = time.monotonic()
            server.publish(observation, command, explorer)
            publish_s.append(time.monotonic() - began)

        # 60 steps of every topic, the maps every step: ~20 MB for a client that takes none of it.
        run_episode(grid, start_poses(MAP)[0], make_planner("nearest"), ObservedAsPrediction(), steps=60,
                    on_observation=publish)
        assert len(publish_s) == 60 and max(publish_s) < 0.5, "publishing only queues: it never waits for a client"
        began = time.monotonic()
        server.close()
        took = time.monotonic() - began
        assert took < CLIENT_WAIT_S + 3, f"close took {took:.1f} s"
        assert server.closed and _port_is_free(server.port)
        # The SDK's stop is still waiting for that client's connection (else this test would test nothing).
        assert server.stopping is not None and server.stopping.daemon
    finally:
        client.close()
        server.close()
    # The client gone, its connection ends, and the stop with it.
    stopping = server.stopping
    if stopping is not None:
        stopping.join(10)
    assert server.stopping is None and _threads() <= threads


@pytest.mark.slow
def test_explore_live_exits_in_time_though_a_client_stopped_reading(tmp_path):
    """The command in its own process, a client in this one that subscribes to everything and then never reads:
    the paced run, its hold and its exit take a bounded time (without the fix, the process never exits while the
    client's socket lives)."""
    pytest.importorskip("foxglove")
    pytest.importorskip("websockets")
    command = [sys.executable, "-m", "superex_deploy.cli", "explore", "--pipeline", "nearest", "--map", MAP,
               "--steps", "40", "--planner", "nearest", "--predictor", "observed", "--gif-every", "0",
               "--live", "127.0.0.1:0", "--live-every", "0", "--live-pace", "20", "--live-hold", "1",
               "--out", str(tmp_path / "run")]
    process = subprocess.Popen(command, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True,
                               cwd=Path(__file__).resolve().parents[1])
    lines: queue.Queue = queue.Queue()
    reader = threading.Thread(target=lambda: [lines.put(line) for line in process.stderr], daemon=True)
    reader.start()
    client = None
    try:
        url, deadline = None, time.monotonic() + 120
        while url is None:
            line = lines.get(timeout=max(0.1, deadline - time.monotonic()))
            if "live view on ws://" in line:
                url = line.split("live view on ")[1].split()[0]
        host, port = url[len("ws://"):].rsplit(":", 1)
        client = _stalled_client(host, int(port))
        began = time.monotonic()
        code = process.wait(timeout=60)  # the run 2 s, the hold 1 s, the stop's wait CLIENT_WAIT_S
        took = time.monotonic() - began
    finally:
        if process.poll() is None:
            process.kill()
            process.wait(10)
        if client is not None:
            client.close()
    reader.join(10)
    err = "".join(list(lines.queue))
    assert code == 0, err
    assert "without waiting for a client that stopped reading" in err, err
    assert took < 2 + 1 + CLIENT_WAIT_S + 15, f"the command took {took:.1f} s after the client subscribed"
    assert (tmp_path / "run" / "metrics.json").exists()


# --- Pacing and the hold -------------------------------------------------------------------------------------------


def _publish_steps(server: LiveServer, stamps, pause_after=None) -> list:
    """Publish small steps stamped ``stamps`` (sleeping ``pause_after[k]`` seconds after step k: a slow step);
    the wall-clock time each was published at."""
    times = []
    for k, stamp in enumerate(stamps):
        step = _step([(0.5, 0.5), (1.0, 1.0)], np.full(5, 2.0, np.float32), stamp)
        explorer = SimpleNamespace(frame=step.frame, observed=step.observed, evidence=step.evidence)
        server.publish(step.observation, step.command, explorer)
        times.append(time.monotonic())
        if pause_after and k in pause_after:
            time.sleep(pause_after[k])
    return times


def test_publish_paces_the_steps_at_a_rate_or_at_their_stamps():
    pytest.importorskip("foxglove")
    with LiveServer("127.0.0.1", 0, pace_hz=10) as server:  # 5 steps at 10 Hz, whatever their stamps
        times = _publish_steps(server, [0.0] * 5)
    assert times[-1] - times[0] >= 0.4 - 0.01 and all(b - a >= 0.1 - 0.01 for a, b in zip(times, times[1:]))
    with LiveServer("127.0.0.1", 0, pace_hz=None) as server:  # at the stamps, in real time
        times = _publish_steps(server, [10.0, 10.1, 10.3, 10.35])
    # Paced against the first step: a step published late shortens the next gap, never the time since the first.
    since = np.asarray(times) - times[0]
    assert np.all(since >= np.array([0.0, 0.1, 0.3, 0.35]) - 0.01), since
    with LiveServer("127.0.0.1", 0, pace_hz=None) as server:  # a long gap in the stamps is cut to a second
        times = _publish_steps(server, [0.0, 3600.0])
    assert 0.99 <= times[1] - times[0] < 2.0
    with LiveServer("127.0.0.1", 0, pace_hz=10) as server:  # a slow step is not made up for by hurrying
        times = _publish_steps(server, [0.0] * 4, pause_after={0: 0.35})
    assert all(b - a >= 0.1 - 0.01 for a, b in zip(times[1:], times[2:])), np.diff(times)
    with LiveServer("127.0.0.1", 0) as server:  # the class's default: 0, as fast as they come
        assert server.pace_hz == 0
        times = _publish_steps(server, [0.0, 0.1, 0.2, 0.3, 0.4])
    assert times[-1] - times[0] < 0.3
    for bad in (-1, float("nan"), float("inf"), "10"):
        with pytest.raises(ValueError, match="--live-pace must be a rate in Hz >= 0"):
            LiveServer("127.0.0.1", 0, pace_hz=bad)
    with LiveServer("127.0.0.1", 0) as server:
        with pytest.raises(ValueError, match="--live-hold must be a number of seconds >= 0"):
            server.hold(-1)
    with pytest.raises(ValueError, match="--live-hold"):
        with live_view(("127.0.0.1", 0), 0.5, hold_s=float("nan")):
            pass


def _publish_times(monkeypatch) -> list:
    """Record when each LiveServer.publish returns."""
    times = []
    publish = LiveServer.publish

    def timed(self, *args):
        publish(self, *args)
        times.append(time.monotonic())

    monkeypatch.setattr(LiveServer, "publish", timed)
    return times


def test_explore_and_replay_live_are_paced_for_a_viewer(tmp_path, monkeypatch):
    pytest.importorskip("foxglove")
    from superex_deploy.cli import main

    times = _publish_times(monkeypatch)
    common = ["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "5", "--planner", "nearest", "--predictor",
              "observed", "--gif-every", "0", "--live", "127.0.0.1:0", "--live-hold", "0"]
    # The default: the simulated sensor's rate, one step per WorldConfig.step_s = 0.1 s.
    assert main(common + ["--out", str(tmp_path / "paced"), "--record", str(tmp_path / "ep.mcap")]) == 0
    assert len(times) == 5 and times[-1] - times[0] >= 0.4 - 0.01, np.diff(times)
    times.clear()
    assert main(common + ["--live-pace", "4", "--out", str(tmp_path / "slow")]) == 0
    assert len(times) == 5 and times[-1] - times[0] >= 1.0 - 0.01, np.diff(times)
    times.clear()
    # A replay follows its recording's stamps: 0.0 .. 0.4 s.
    assert main(["replay", str(tmp_path / "ep.mcap"), "--live", "127.0.0.1:0", "--live-hold", "0", "--out",
                 str(tmp_path / "replay")]) == 0
    assert len(times) == 5 and times[-1] - times[0] >= 0.4 - 0.01, np.diff(times)


def _hold_started(monkeypatch) -> threading.Event:
    """An event set when a LiveServer's hold begins."""
    started = threading.Event()
    hold = LiveServer.hold

    def hold_and_say(self, seconds):
        started.set()
        return hold(self, seconds)

    monkeypatch.setattr(LiveServer, "hold", hold_and_say)
    return started


def test_the_last_state_stays_served_for_the_hold_then_the_command_returns(tmp_path, capsys, monkeypatch):
    pytest.importorskip("foxglove")
    websockets_client = pytest.importorskip("websockets.sync.client")
    from superex_deploy.cli import main

    started = _hold_started(monkeypatch)
    port = _free_port()
    threads = _threads()
    seen: dict = {}

    def late_viewer():  # connects once the run is over, during the hold
        try:
            if not started.wait(60):
                return
            with websockets_client.connect(f"ws://127.0.0.1:{port}", subprotocols=[SUBPROTOCOL], max_size=None,
                                           open_timeout=10, close_timeout=2) as ws:
                deadline = time.monotonic() + 10
                ids = _advertised(ws, deadline, {"/map", "/pose"})
                ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": 1, "channelId": ids["/map"]},
                                                                         {"id": 2, "channelId": ids["/pose"]}]}))
                topics = {1: "/map", 2: "/pose"}
                while set(seen) != {"/map", "/pose"} and time.monotonic() < deadline:
                    frame = _receive(ws, deadline)
                    if isinstance(frame, bytes) and frame[0] == MESSAGE_DATA:
                        subscription, stamp_ns = struct.unpack_from("<IQ", frame, 1)
                        seen[topics[subscription]] = (stamp_ns, frame[13:])
        except Exception as error:  # reported by the assertions below
            seen["error"] = repr(error)

    viewer = threading.Thread(target=late_viewer)
    viewer.start()
    began = time.monotonic()
    try:
        code = main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "3", "--planner", "nearest",
                     "--predictor", "observed", "--gif-every", "0", "--live", f"127.0.0.1:{port}",
                     "--live-pace", "0", "--live-hold", "2.5", "--out", str(tmp_path / "run")])
        took = time.monotonic() - began
    finally:
        started.set()
        viewer.join(30)
    assert code == 0 and not viewer.is_alive()
    assert "error" not in seen and set(seen) == {"/map", "/pose"}, seen
    err = capsys.readouterr().err
    assert f"the run is over; its last state stays on ws://127.0.0.1:{port} for 2.5 s more" in err
    # The last step's state (step 2, at 0.2 s): its pose, and the map that step left.
    metrics = json.loads((tmp_path / "run" / "metrics.json").read_text())
    assert metrics["steps"] == 3
    assert seen["/pose"][0] == round(0.2 * 1e9) == seen["/map"][0]
    final_map = _decoder(channel("/map"))(seen["/map"][1])
    assert final_map.header.frame_id == "map" and len(final_map.data) == final_map.info.width * final_map.info.height
    assert 2.5 <= took < 2.5 + 30, f"took {took:.1f} s"
    assert _port_is_free(port) and _threads() <= threads


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_ctrl_c_ends_the_hold_at_once_and_the_run_keeps_its_result(tmp_path, capsys, monkeypatch, signum):
    pytest.importorskip("foxglove")
    from superex_deploy.cli import main

    started = _hold_started(monkeypatch)
    port = _free_port()
    threads = _threads()

    def interrupt():
        if started.wait(60):
            time.sleep(0.2)  # into the hold's wait
            os.kill(os.getpid(), signum)

    interrupter = threading.Thread(target=interrupt)
    interrupter.start()
    try:
        began = time.monotonic()
        code = main(["explore", "--pipeline", "nearest", "--map", MAP, "--steps", "2", "--planner", "nearest",
                     "--predictor", "observed", "--gif-every", "0", "--live", f"127.0.0.1:{port}",
                     "--live-pace", "0", "--live-hold", "60",
                     "--out", str(tmp_path / "run")])
        took = time.monotonic() - began
    finally:
        started.set()
        interrupter.join(70)
    assert code == 0 and took < 30, f"exit {code} after {took:.1f} s"
    assert "stopped by" not in capsys.readouterr().err
    assert json.loads((tmp_path / "run" / "metrics.json").read_text())["steps"] == 2
    assert _port_is_free(port) and _threads() <= threads

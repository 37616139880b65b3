"""The live view: an episode's topics served on a local Foxglove WebSocket while it runs (``superex explore --live``,
``superex replay --live``).

:class:`LiveServer` publishes every channel of :data:`~superex_deploy.recording.channels.CHANNELS`: the recording's
topics (the same types, ``ros2msg`` schemas and CDR messages an MCAP recording holds) and the live view's own
(``/tf``, ``/goal``, ``/prediction``, ``/evidence``). Open it in Foxglove: *Open connection* -> *Foxglove WebSocket*
-> ``ws://127.0.0.1:8765``.

Publishing costs the episode little:

* a topic no client subscribes to is not even built;
* the large messages (the maps, the prediction, the evidence, the SPAD frame: ``grid`` channels) go out at most
  once per ``every_s`` seconds of the observations' clock (simulated time), and at the last step;
* the large arrays' CDR bytes (a grid's cells, a scan's ranges, a path's poses) are laid out with numpy, not value
  by value (:func:`encode`: the same bytes the MCAP writer's encoder makes);
* sending runs on the server's own threads: a slow client loses its oldest queued messages (``backlog`` per client),
  the episode never waits for it.

A client that stops reading (a laptop gone to sleep) never holds the run or its end: publishing only queues (the
SDK drops a slow client's oldest messages, and gives up on a client whose control messages pile up), and
:meth:`LiveServer.close` waits at most :data:`CLIENT_WAIT_S` for the clients to take the server's goodbye. The SDK's
``stop()`` waits for every client's connection to end, and a connection to a client that does not read never ends
(its last write, the close frame, waits for room in a socket that never drains): so the stop runs on a daemon thread
and the command goes on without it once the listener is closed; that connection closes when the client goes away or
the process exits.

A simulated episode runs far faster than real time (hundreds of steps a second); a viewer would see it over before
it had connected. So the live view can pace the episode (``pace_hz``: by default, in the commands, at the
observations' clock: the simulated sensor's 10 Hz, or a recording's stamps) and serve its last state for a while
after the run (:meth:`LiveServer.hold`, ``--live-hold``): a client that subscribes then gets the final map, pose,
path and prediction.

The server needs the ``foxglove-sdk`` package (the ``live`` extra), imported only when a server starts.
"""

from __future__ import annotations

import contextlib
import errno
import math
import socket
import struct
import sys
import threading
import time
from typing import Iterator, Optional

import numpy as np

from superex_deploy.messages import Command, Observation
from superex_deploy.recording.channels import (CHANNELS, MESSAGE_ENCODING, SCHEMA_ENCODING, ChannelSpec, StepData,
                                               plain_values)

__all__ = ["CLIENT_WAIT_S", "DEFAULT_ADDRESS", "DEFAULT_HOLD_S", "MISSING_EXTRA", "STOP_WAIT_S", "LiveServer",
           "busy_port_message", "encode", "live_view", "parse_address"]

DEFAULT_ADDRESS = ("127.0.0.1", 8765)
"""Where ``--live`` serves without an address: this machine only, Foxglove's default port."""
MISSING_EXTRA = "--live needs the foxglove-sdk package, which is not installed: pip install 'superex[live]'"
"""The error of ``--live`` without the ``live`` extra."""
DEFAULT_HOLD_S = 10.0
"""How long ``--live`` serves the last state after the run, without ``--live-hold``."""


def busy_port_message(host: str, port: int) -> str:
    """The error of a server whose port another program holds."""
    return (f"--live {host}:{port}: the port is already in use (another program, or another superex --live, listens "
            f"there); stop it or choose another port: --live {host}:PORT")


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (``[::1]:PORT`` for IPv6) as ``(host, port)``; port 0 takes any free port.

    Raises:
        ValueError: no port, a port that is not an integer in 0..65535, an empty host.
    """
    host, separator, port_text = str(text).rpartition(":")
    host = host[1:-1] if host.startswith("[") and host.endswith("]") else host
    try:
        port = int(port_text)
    except ValueError:
        port = -1
    if not separator or not host or not 0 <= port <= 65535:
        raise ValueError(f"expected HOST:PORT with a port in 0..65535 (e.g. 127.0.0.1:8765), got {text!r}")
    return host, port


STOP_WAIT_S = 5.0
"""How long :meth:`LiveServer.close` waits at most for the server's listener to let its port go (it takes about a
millisecond)."""
CLIENT_WAIT_S = 2.0
"""How long :meth:`LiveServer.close` waits at most for the clients to take the server's goodbye (what was queued for
them, then a close frame: milliseconds for a client that reads); a client that stopped reading never does, and the
stop goes on without it (:attr:`LiveServer.stopping`)."""
_SETTLE_S = (0.05, 0.5)
"""When :meth:`LiveServer.hold` sends the last state again after a client subscribes (seconds after the SDK reports
it: the SDK tells the listener just before the subscription takes effect, so once soon and once more later)."""


def _check_number(option: str, value, what: str) -> float:
    """``value`` as a float, or one clear ValueError naming ``option`` (not a finite number >= 0)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < 0:
        raise ValueError(f"{option} must be {what} >= 0, got {value!r}")
    return float(value)


_LONGEST_GAP_S = 1.0
"""Pacing at the stamps, the longest wait for one step: a longer gap in a recording's stamps is cut to this."""


class _Pacer:
    """Holds a loop to a rate: :meth:`wait` returns once the step's time has come, at ``hz`` steps a second, or
    (``hz`` None) at the steps' stamps in real time (a gap longer than :data:`_LONGEST_GAP_S` cut to it); ``hz`` 0:
    at once. A step that comes late (a slow step) is not made up for by hurrying the next ones: the schedule starts
    again from it."""

    def __init__(self, hz: Optional[float]):
        self.hz = hz
        self._steps = 0
        self._anchor: Optional[tuple[float, float]] = None  # (wall clock, step time) the schedule counts from

    def wait(self, stamp_s: float) -> None:
        if self.hz == 0:
            return
        at = stamp_s if self.hz is None else self._steps / self.hz
        self._steps += 1
        now = time.monotonic()
        if self._anchor is None or at < self._anchor[1]:  # the first step, or a clock that went back
            self._anchor = (now, at)
            return
        due = self._anchor[0] + (at - self._anchor[1])
        if due <= now:
            self._anchor = (now, at)  # late: go on from here
            return
        if self.hz is None and due - now > _LONGEST_GAP_S:
            due = now + _LONGEST_GAP_S
            self._anchor = (due, at)
        time.sleep(due - now)


def _wait_until_free(host: str, port: int, timeout_s: float = STOP_WAIT_S) -> None:
    """Return once a new listener could bind ``(host, port)`` (as a server does: ``SO_REUSEADDR``, so that the
    closed connections' ``TIME_WAIT`` does not count), or after ``timeout_s``; an address this cannot probe returns
    at once."""
    deadline = time.monotonic() + timeout_s
    try:
        family = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)[0][0]
    except OSError:
        return
    while True:
        with socket.socket(family, socket.SOCK_STREAM) as probe:
            probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                probe.bind((host, port))
                return
            except OSError as error:
                if error.errno != errno.EADDRINUSE or time.monotonic() > deadline:
                    return
        time.sleep(0.002)


def _foxglove():
    try:
        import foxglove
    except ImportError:
        raise ValueError(MISSING_EXTRA) from None
    return foxglove


def _grid_bytes(message: dict, encoder) -> Optional[bytes]:
    """An OccupancyGrid: its last field, int8 ``data``, is a uint32 count then one byte per cell (no padding)."""
    data = message.get("data")
    if not isinstance(data, np.ndarray):
        return None
    head = encoder(plain_values({**message, "data": []}))  # ends with the count 0
    return head[:-4] + struct.pack("<I", data.size) + np.ascontiguousarray(data, np.int8).tobytes()


def _scan_bytes(message: dict, encoder) -> Optional[bytes]:
    """A LaserScan without intensities: float32 ``ranges`` (a count, 4-byte values) then the count 0."""
    ranges = message.get("ranges")
    if not isinstance(ranges, np.ndarray) or len(message.get("intensities", ())) != 0:
        return None
    head = encoder(plain_values({**message, "ranges": []}))  # ends with the counts 0 of ranges and intensities
    return (head[:-8] + struct.pack("<I", ranges.size) + np.asarray(ranges).astype("<f4").ravel().tobytes()
            + struct.pack("<I", 0))


def _path_bytes(message: dict, encoder) -> Optional[bytes]:
    """A Path whose poses share one header: each pose is that header (stamp, frame id), padding to 8 bytes and 7
    float64 (position, orientation); every pose after the first starts 8-byte aligned, so they share one layout."""
    poses = message.get("poses") or []
    head = encoder(plain_values({**message, "poses": []}))  # ends with the count 0
    if not poses:
        return head
    header = poses[0]["header"]
    if any(pose["header"] != header for pose in poses):
        return None
    frame = header["frame_id"].encode() + b"\0"
    element = struct.pack("<iII", header["stamp"]["sec"], header["stamp"]["nanosec"], len(frame)) + frame
    values = np.array([(p["position"]["x"], p["position"]["y"], p["position"]["z"], p["orientation"]["x"],
                        p["orientation"]["y"], p["orientation"]["z"], p["orientation"]["w"])
                       for p in (pose["pose"] for pose in poses)], "<f8")
    first_pad = -(len(head) - 4 + len(element)) % 8  # alignment counts from after the 4-byte encapsulation header
    pad = -len(element) % 8
    rest = np.zeros((len(poses) - 1, len(element) + pad + 56), np.uint8)
    rest[:, :len(element)] = np.frombuffer(element, np.uint8)
    rest[:, len(element) + pad:] = values[1:].view(np.uint8).reshape(-1, 56)
    return (head[:-4] + struct.pack("<I", len(poses)) + element + bytes(first_pad) + values[0].tobytes()
            + rest.tobytes())


_FAST = {"nav_msgs/msg/OccupancyGrid": _grid_bytes, "sensor_msgs/msg/LaserScan": _scan_bytes,
         "nav_msgs/msg/Path": _path_bytes}


def encode(spec: ChannelSpec, message: dict, encoder) -> bytes:
    """The CDR bytes of ``message`` on ``spec``'s channel: those ``encoder`` (``mcap_ros2``'s, of ``spec``'s
    schema: the MCAP writer's) makes of it. Its large parts are laid out with numpy where the encoder would write
    them one value at a time: a grid's cells, a scan's ranges, a path's poses (the same bytes; tested)."""
    fast = _FAST.get(spec.type_name)
    data = None if fast is None else fast(message, encoder)
    return encoder(plain_values(message)) if data is None else data


class LiveServer:
    """A Foxglove WebSocket server of an episode's topics; use as a context manager (or call :meth:`close`).

    Args:
        host: the address to listen on (``127.0.0.1``: this machine only; ``0.0.0.0``: every interface).
        port: the port; 0 takes a free one (:attr:`port` says which).
        every_s: publish the ``grid`` channels (maps, prediction, evidence, SPAD frame) at most once per this many
            seconds of the observations' clock, and at the last step (0: every step).
        backlog: messages queued per client; a client that falls further behind loses the oldest.
        pace_hz: how fast :meth:`publish` lets the steps go: at most this many a second (it waits before a step
            that comes early); None: at the observations' stamps, in real time (a simulated episode at its
            sensor's rate, one step per ``WorldConfig.step_s``; a replay as recorded); 0: as fast as they come.

    Attributes:
        host, every_s, pace_hz: as given.
        port: the port it listens on.
        published: topic -> messages published so far.

    Raises:
        ValueError: the ``foxglove-sdk`` package is missing (:data:`MISSING_EXTRA`), the port is in use
            (:func:`busy_port_message`), a bad ``every_s``, ``backlog`` or ``pace_hz``, or the server cannot start
            otherwise.
    """

    def __init__(self, host: str = DEFAULT_ADDRESS[0], port: int = DEFAULT_ADDRESS[1], every_s: float = 0.5,
                 backlog: int = 256, pace_hz: Optional[float] = 0.0):
        foxglove = _foxglove()
        from mcap_ros2._dynamic import serialize_dynamic  # the encoder of mcap_ros2's Writer: the MCAP's bytes

        every_s = _check_number("--live-every", every_s, "a number of seconds")
        if pace_hz is not None:
            pace_hz = _check_number("--live-pace", pace_hz, "a rate in Hz")
        if int(backlog) < 1:
            raise ValueError(f"backlog must be >= 1, got {backlog!r}")
        self.host, self.every_s, self.pace_hz = host, every_s, pace_hz
        self._pacer = _Pacer(pace_hz)
        self._last: Optional[tuple] = None  # the last step published: (observation, command, explorer)
        self._subscribed = threading.Event()  # set by the server's thread when a client subscribes
        self._stopper: Optional[threading.Thread] = None
        self._server = None
        self._context = foxglove.Context()  # its own: the channels reach this server alone
        self._channels, self._encoders = {}, {}
        for spec in CHANNELS:
            schema = foxglove.Schema(name=spec.type_name, encoding=SCHEMA_ENCODING, data=spec.schema.encode())
            self._channels[spec.topic] = foxglove.Channel(spec.topic, schema=schema, message_encoding=MESSAGE_ENCODING,
                                                          context=self._context)
            self._encoders[spec.topic] = serialize_dynamic(spec.type_name, spec.schema)[spec.type_name]
        try:
            self._server = foxglove.start_server(name="superex", host=host, port=int(port), context=self._context,
                                                 capabilities=[foxglove.Capability.Time],
                                                 server_listener=_listener(self._subscribed),
                                                 message_backlog_size=int(backlog))
        except RuntimeError as error:
            self._close_channels()
            if "in use" in str(error).lower():
                raise ValueError(busy_port_message(host, port)) from None
            raise ValueError(f"--live {host}:{port}: the live view could not start ({error})") from None
        self.port = int(self._server.port)
        self.published = {spec.topic: 0 for spec in CHANNELS}
        self._last_grid_s: Optional[float] = None

    @property
    def url(self) -> str:
        """The address a Foxglove client opens (``ws://HOST:PORT``)."""
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    @property
    def closed(self) -> bool:
        """Whether the server has stopped (its listener closed)."""
        return self._server is None

    @property
    def stopping(self) -> Optional[threading.Thread]:
        """After :meth:`close`: the daemon thread still stopping the server, waiting for a client that stopped
        reading to let its connection go; None once every connection has ended (and before :meth:`close`)."""
        stopper = self._stopper
        return stopper if stopper is not None and stopper.is_alive() else None

    def channel_ids(self) -> dict:
        """Topic -> the id its channel is advertised with."""
        return {topic: channel.id() for topic, channel in self._channels.items()}

    def subscribed_topics(self) -> list:
        """The topics at least one client subscribes to (the ones :meth:`publish` builds)."""
        return [topic for topic, channel in self._channels.items() if channel.has_sinks()]

    def publish(self, observation: Observation, command: Command, explorer) -> None:
        """Publish one step (the ``on_observation`` callback of :func:`superex_deploy.evaluation.episodes.run_episode`):
        each subscribed topic's message, stamped with the observation's time, and that time as the server's clock;
        first, wait until the step's time has come (``pace_hz``). Never waits for a client.

        Args:
            observation, command: the step's.
            explorer: the :class:`~superex_deploy.onboard.explorer.Explorer` after the step (its ``frame``,
                ``observed`` and ``evidence`` are read, on the steps the grids go out, and by :meth:`hold`).

        Raises:
            RuntimeError: after :meth:`close`.
        """
        if self._server is None:
            raise RuntimeError("the live view was closed")
        stamp = observation.stamp_s
        self._pacer.wait(stamp)
        self._last = (observation, command, explorer)
        last = self._last_grid_s
        grids = last is None or stamp < last or stamp - last >= self.every_s or bool(command.finished)
        if grids:
            self._last_grid_s = stamp
        wanted = [spec for spec in CHANNELS if (grids or not spec.grid) and self._channels[spec.topic].has_sinks()]
        nanoseconds = int(round(stamp * 1e9))
        if wanted:
            data = self._step_data(grids)
            for spec in wanted:
                message = spec.build(data)
                if message is not None:
                    self._channels[spec.topic].log(encode(spec, message, self._encoders[spec.topic]),
                                                   log_time=nanoseconds)
                    self.published[spec.topic] += 1
        self._server.broadcast_time(nanoseconds)

    def _step_data(self, grids: bool) -> StepData:
        """What the channels build the last step published from (without the grids' arrays: ``grids`` False)."""
        observation, command, explorer = self._last
        prediction = getattr(command.prediction, "mean", None) if grids else None
        return StepData(observation, command, explorer.frame, observed=explorer.observed if grids else None,
                        prediction=prediction, evidence=getattr(explorer, "evidence", None) if grids else None)

    def hold(self, seconds: float) -> bool:
        """Serve the last step published, all of it (the maps too, whatever ``every_s``), for ``seconds`` more:
        to the clients subscribed now, and to every client that subscribes meanwhile (sent again to each
        channel's subscribers when one subscribes). A KeyboardInterrupt (Ctrl-C; the commands' SIGINT or SIGTERM)
        ends the hold at once.

        Returns:
            True after the whole hold, False when it was interrupted.

        Raises:
            ValueError: ``seconds`` not a number >= 0.
            RuntimeError: after :meth:`close`.
        """
        seconds = _check_number("--live-hold", seconds, "a number of seconds")
        if self._server is None:
            raise RuntimeError("the live view was closed")
        deadline = time.monotonic() + seconds
        try:
            final = self._final_messages()
            due = [time.monotonic()]  # when to send the last state again: now, to the clients subscribed already
            while True:
                now = time.monotonic()
                if self._subscribed.is_set():
                    self._subscribed.clear()
                    due += [now + settle for settle in _SETTLE_S]
                if due and min(due) <= now:
                    due = [at for at in due if at > now]
                    self._send(final)
                    continue
                if now >= deadline:
                    return True
                self._subscribed.wait(min([deadline] + due) - now)
        except KeyboardInterrupt:
            return False

    def _final_messages(self) -> tuple[list, int]:
        """Every channel's message of the last step published, encoded, and its stamp (ns); none before a step."""
        if self._last is None:
            return [], 0
        data = self._step_data(grids=True)
        messages = []
        for spec in CHANNELS:
            message = spec.build(data)
            if message is not None:
                messages.append((spec.topic, encode(spec, message, self._encoders[spec.topic])))
        return messages, int(round(data.observation.stamp_s * 1e9))

    def _send(self, final: tuple[list, int]) -> None:
        messages, nanoseconds = final
        if not messages:
            return
        for topic, data in messages:
            if self._channels[topic].has_sinks():
                self._channels[topic].log(data, log_time=nanoseconds)
                self.published[topic] += 1
        self._server.broadcast_time(nanoseconds)

    def close(self, wait_s: float = CLIENT_WAIT_S) -> None:
        """Stop the server and close the channels; when this returns the port is free (the server stops its
        listener on its own thread: this waits for it, up to :data:`STOP_WAIT_S`). Idempotent.

        The SDK's stop also waits for every client's connection to end, which a client that stopped reading never
        lets happen: it runs on a daemon thread, waited for ``wait_s`` seconds at most (:data:`CLIENT_WAIT_S`);
        then :attr:`stopping` is that thread, and the connection ends when the client goes away or the process
        exits."""
        server, self._server = self._server, None
        try:
            if server is not None:
                self._stopper = threading.Thread(target=server.stop, name="superex-live-stop", daemon=True)
                self._stopper.start()
                self._stopper.join(wait_s)
                _wait_until_free(self.host, self.port)
        finally:
            self._close_channels()

    def _close_channels(self) -> None:
        channels, self._channels = self._channels, {}
        for channel in channels.values():
            channel.close()

    def __enter__(self) -> "LiveServer":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()


def _listener(subscribed: threading.Event):
    """A foxglove ``ServerListener`` that sets ``subscribed`` when a client subscribes (on the server's thread)."""
    from foxglove.websocket import ServerListener

    class Subscriptions(ServerListener):
        def on_subscribe(self, client, channel) -> None:
            subscribed.set()

    return Subscriptions()


@contextlib.contextmanager
def live_view(address: Optional[tuple], every_s: float, command: str = "superex", pace_hz: Optional[float] = 0.0,
              hold_s: float = 0.0) -> Iterator[Optional[LiveServer]]:
    """A :class:`LiveServer` on ``address`` (``(host, port)``) for the ``with`` block, said on stderr; when the
    block ends normally, it serves the last state for ``hold_s`` seconds more (:meth:`LiveServer.hold`, said on
    stderr; Ctrl-C ends it); then, or at once when the block ends otherwise (an exception, a signal), it is stopped
    (a client that stopped reading is not waited for: said on stderr). None (no server) when ``address`` is None.

    Raises:
        ValueError: as :class:`LiveServer`, or a bad ``hold_s``.
    """
    if address is None:
        yield None
        return
    hold_s = _check_number("--live-hold", hold_s, "a number of seconds")
    server = LiveServer(address[0], address[1], every_s=every_s, pace_hz=pace_hz)
    try:
        print(f"{command}: live view on {server.url} (Foxglove: Open connection -> Foxglove WebSocket)",
              file=sys.stderr, flush=True)
        yield server
        if hold_s > 0:
            print(f"{command}: the run is over; its last state stays on {server.url} for {hold_s:g} s more "
                  f"(--live-hold; Ctrl-C ends it now)", file=sys.stderr, flush=True)
            server.hold(hold_s)
    finally:
        server.close()
        if server.stopping is not None:
            print(f"{command}: live view stopped without waiting for a client that stopped reading (its connection "
                  f"closes when it goes away or this command exits)", file=sys.stderr, flush=True)

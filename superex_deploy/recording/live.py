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

The server needs the ``foxglove-sdk`` package (the ``live`` extra), imported only when a server starts.
"""

from __future__ import annotations

import contextlib
import errno
import math
import socket
import struct
import sys
import time
from typing import Iterator, Optional

import numpy as np

from superex_deploy.messages import Command, Observation
from superex_deploy.recording.channels import (CHANNELS, MESSAGE_ENCODING, SCHEMA_ENCODING, ChannelSpec, StepData,
                                               plain_values)

__all__ = ["DEFAULT_ADDRESS", "MISSING_EXTRA", "STOP_WAIT_S", "LiveServer", "busy_port_message", "encode", "live_view",
           "parse_address"]

DEFAULT_ADDRESS = ("127.0.0.1", 8765)
"""Where ``--live`` serves without an address: this machine only, Foxglove's default port."""
MISSING_EXTRA = "--live needs the foxglove-sdk package, which is not installed: pip install 'superex[live]'"
"""The error of ``--live`` without the ``live`` extra."""


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

    Attributes:
        host, every_s: as given.
        port: the port it listens on.
        published: topic -> messages published so far.

    Raises:
        ValueError: the ``foxglove-sdk`` package is missing (:data:`MISSING_EXTRA`), the port is in use
            (:func:`busy_port_message`), a bad ``every_s`` or ``backlog``, or the server cannot start otherwise.
    """

    def __init__(self, host: str = DEFAULT_ADDRESS[0], port: int = DEFAULT_ADDRESS[1], every_s: float = 0.5,
                 backlog: int = 256):
        foxglove = _foxglove()
        from mcap_ros2._dynamic import serialize_dynamic  # the encoder of mcap_ros2's Writer: the MCAP's bytes

        if not (isinstance(every_s, (int, float)) and math.isfinite(every_s) and every_s >= 0):
            raise ValueError(f"--live-every must be a number of seconds >= 0, got {every_s!r}")
        if int(backlog) < 1:
            raise ValueError(f"backlog must be >= 1, got {backlog!r}")
        self.host, self.every_s = host, float(every_s)
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
        """Whether the server has stopped."""
        return self._server is None

    def channel_ids(self) -> dict:
        """Topic -> the id its channel is advertised with."""
        return {topic: channel.id() for topic, channel in self._channels.items()}

    def subscribed_topics(self) -> list:
        """The topics at least one client subscribes to (the ones :meth:`publish` builds)."""
        return [topic for topic, channel in self._channels.items() if channel.has_sinks()]

    def publish(self, observation: Observation, command: Command, explorer) -> None:
        """Publish one step (the ``on_observation`` callback of :func:`superex_deploy.sim.episode.run_episode`):
        each subscribed topic's message, stamped with the observation's time, and that time as the server's clock.

        Args:
            observation, command: the step's.
            explorer: the :class:`~superex_deploy.onboard.explorer.Explorer` after the step (its ``frame``,
                ``observed`` and ``evidence`` are read, on the steps the grids go out).

        Raises:
            RuntimeError: after :meth:`close`.
        """
        if self._server is None:
            raise RuntimeError("the live view was closed")
        stamp = observation.stamp_s
        last = self._last_grid_s
        grids = last is None or stamp < last or stamp - last >= self.every_s or bool(command.finished)
        if grids:
            self._last_grid_s = stamp
        wanted = [spec for spec in CHANNELS if (grids or not spec.grid) and self._channels[spec.topic].has_sinks()]
        nanoseconds = int(round(stamp * 1e9))
        if wanted:
            prediction = getattr(command.prediction, "mean", None) if grids else None
            data = StepData(observation, command, explorer.frame, observed=explorer.observed if grids else None,
                            prediction=prediction, evidence=getattr(explorer, "evidence", None) if grids else None)
            for spec in wanted:
                message = spec.build(data)
                if message is not None:
                    self._channels[spec.topic].log(encode(spec, message, self._encoders[spec.topic]),
                                                   log_time=nanoseconds)
                    self.published[spec.topic] += 1
        self._server.broadcast_time(nanoseconds)

    def close(self) -> None:
        """Stop the server and close the channels; when this returns the port is free (the server stops its
        listener on its own thread: this waits for it, up to ``STOP_WAIT_S``). Idempotent."""
        server, self._server = self._server, None
        try:
            if server is not None:
                server.stop()
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


@contextlib.contextmanager
def live_view(address: Optional[tuple], every_s: float, command: str = "superex") -> Iterator[Optional[LiveServer]]:
    """A :class:`LiveServer` on ``address`` (``(host, port)``) for the ``with`` block, said on stderr, stopped when
    the block ends however it ends (an exception, a signal); None (no server) when ``address`` is None.

    Raises:
        ValueError: as :class:`LiveServer`.
    """
    if address is None:
        yield None
        return
    with LiveServer(address[0], address[1], every_s=every_s) as server:
        print(f"{command}: live view on {server.url} (Foxglove: Open connection -> Foxglove WebSocket)",
              file=sys.stderr, flush=True)
        yield server

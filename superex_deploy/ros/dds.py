"""A minimal ROS-2-like participant on Cyclone DDS: publishers and subscriptions that ROS 2 nodes (``rmw_cyclonedds``,
Iron and later) see as their own, without a ROS install.

What makes a DDS endpoint a ROS 2 one, and what :class:`RosParticipant` does for each:

* **names**: ROS topic ``/scan`` is DDS topic ``rt/scan`` with type ``sensor_msgs::msg::dds_::LaserScan_``;
  :meth:`RosParticipant.resolve` expands relative (``scan`` -> ``/<namespace>/scan``) and private (``~/x`` ->
  ``/<namespace>/<node>/x``) names and refuses invalid ones with ROS 2's rules (``rmw_validate_full_topic_name``:
  alphanumerics, ``_`` and ``/``; no ``//``; no trailing ``/``; no token starting with a digit; at most 247
  characters).
* **type hash**: every reader and writer carries ``typehash=RIHS01_<64 hex>;`` in its USER_DATA QoS, as
  ``rmw_cyclonedds_cpp`` puts it there (:func:`~superex_deploy.ros.discovery.type_hash`; how it is computed and why
  it equals ROS 2's: :mod:`superex_deploy.ros.discovery`).
* **QoS** as rmw builds it (:meth:`superex_deploy.ros.qos.RosQos.to_dds`); the participant's USER_DATA is
  ``enclave=/;`` as rmw's.
* **the ROS graph** (``discovery_info=True``): ``ros2 node list`` shows nodes from the ``ros_discovery_info`` topic;
  the participant publishes there its GUID and one node (name, namespace, the GUIDs of its readers and writers) after
  every change (the messages and the topic's rules: :mod:`superex_deploy.ros.discovery`). Its ``Gid`` is Iron's
  (16 bytes): this targets Iron and later; a Humble graph does not parse it, so turn it off there
  (``discovery_info=False``: topics still flow, only the node is missing from ``ros2 node list``).

Nothing here runs in a DDS thread: there are no listeners or callbacks. A loop thread calls :meth:`RosParticipant.wait`
(a wait set over the subscriptions' read conditions) and then ``take`` / ``take_newest``; a sample that fails to
deserialise is counted in ``Subscription.malformed`` and skipped.

**One machine without a network**: ``CYCLONEDDS_URI=$(python -c "from superex_deploy.ros.dds import loopback_config;
print(loopback_config())")`` (or ``RosParticipant(..., config=loopback_config())``) keeps discovery and data on
127.0.0.1, unicast to the participants of this machine. A ROS 2 node started with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` discovers by the same scheme (unicast to ``localhost``, indices up to 32),
so the two should meet; that is not tested here (no ROS install), only our own participants in two processes are.
"""

import math
import os
import re
import threading
from dataclasses import dataclass
from typing import Optional

from cyclonedds._clayer import ddspy_take
from cyclonedds.core import (DDSException, GuardCondition, InstanceState, Policy, Qos, ReadCondition, SampleState,
                             ViewState, WaitSet)
from cyclonedds.domain import Domain, DomainParticipant
from cyclonedds.pub import DataWriter
from cyclonedds.sub import DataReader
from cyclonedds.topic import Topic

from superex_deploy.ros.discovery import (DISCOVERY_TOPIC, Gid, NodeEntitiesInfo, ParticipantEntitiesInfo,
                                          type_hash)
from superex_deploy.ros.idl import MESSAGE_TYPES, field_error, ros_name
from superex_deploy.ros.qos import DISCOVERY_INFO, RosQos

__all__ = ["RosParticipant", "Publisher", "Subscription", "MessageInfo", "loopback_config", "MAX_DOMAIN_ID"]

MAX_DOMAIN_ID = 232
_MAX_TOPIC_LENGTH = 247  # RMW_TOPIC_MAX_NAME_LENGTH: 255 - 8 reserved for prefixes
_ANY = SampleState.Any | ViewState.Any | InstanceState.Any


def loopback_config() -> str:
    """A Cyclone DDS configuration (XML, for ``CYCLONEDDS_URI`` or ``RosParticipant(config=...)``) that keeps
    discovery and data on this machine: the 127.0.0.1 interface, no multicast, unicast discovery of the participants
    at ``localhost`` with participant indices 0..32 (the peer list and index range ``rmw_cyclonedds`` sets for
    ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``). Works with no network but the loopback (tested in a network
    namespace holding only ``lo``)."""
    return ('<CycloneDDS><Domain Id="any"><General><Interfaces><NetworkInterface address="127.0.0.1"/></Interfaces>'
            '<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>'
            '<MaxAutoParticipantIndex>32</MaxAutoParticipantIndex><Peers><Peer address="localhost"/></Peers>'
            '</Discovery></Domain></CycloneDDS>')


def _domain_id(domain_id) -> int:
    if domain_id is None:
        text = os.environ.get("ROS_DOMAIN_ID", "").strip()
        if not text:
            return 0  # rcl: an unset or empty ROS_DOMAIN_ID is the default domain
        if not re.fullmatch(r"\d+", text) or int(text) > MAX_DOMAIN_ID:
            raise ValueError(f"ROS_DOMAIN_ID must be an integer in 0..{MAX_DOMAIN_ID}, got {text!r}")
        return int(text)
    if isinstance(domain_id, bool) or not isinstance(domain_id, int) or not 0 <= domain_id <= MAX_DOMAIN_ID:
        raise ValueError(f"domain_id must be an integer in 0..{MAX_DOMAIN_ID}, got {domain_id!r}")
    return domain_id


def _check_name(name: str, what: str, shown: str, max_length: int = _MAX_TOPIC_LENGTH) -> None:
    """ROS 2's rules for a fully qualified name (``rmw_validate_full_topic_name``); ``shown`` goes in the message."""
    problem = None
    if not name.startswith("/"):
        problem = "must be absolute"
    elif re.search(r"[^A-Za-z0-9_/]", name):
        problem = f"holds {re.search(r'[^A-Za-z0-9_/]', name).group()!r}: only letters, digits, '_' and '/' are allowed"
    elif "//" in name:
        problem = "holds '//'"
    elif re.search(r"/[0-9]", name):
        problem = "has a name token starting with a digit"
    elif len(name) > max_length:
        problem = f"is {len(name)} characters long, more than {max_length}"
    if problem:
        raise ValueError(f"invalid ROS 2 {what} {shown!r}: it {problem}")


@dataclass(frozen=True)
class MessageInfo:
    """What DDS says about a received message: ``source_time_s``, the writer's clock at ``write`` (Unix seconds), and
    ``publication_handle``, the local handle of the writer it came from."""

    source_time_s: float
    publication_handle: int


class _Endpoint:
    def __init__(self, owner: "RosParticipant", topic: str, msg_type, qos: RosQos):
        self.participant, self.topic, self.msg_type, self.qos = owner, topic, msg_type, qos
        self.entity = None

    @property
    def gid(self) -> bytes:
        """The 16-byte DDS GUID of the reader or writer (its ROS 2 gid)."""
        return self._live().guid.bytes

    def _live(self):
        if self.entity is None or self.participant.closed:
            raise RuntimeError(f"the {type(self).__name__.lower()} on {self.topic} was closed")
        return self.entity

    def close(self) -> None:
        """Delete the reader or writer (the participant's :meth:`RosParticipant.close` closes all)."""
        if self.entity is not None:
            entity, self.entity = self.entity, None
            if not self.participant.closed:
                entity.__del__()  # the DDS delete that garbage collection would do, now
                self.participant._forget(self)


class Publisher(_Endpoint):
    """A ROS 2 publisher: a DDS writer on ``rt`` + ``topic`` (made by :meth:`RosParticipant.publisher`)."""

    def publish(self, message) -> None:
        """Send ``message`` (an instance of ``msg_type``) now.

        Raises:
            ValueError: ``message`` is not a ``msg_type`` or a field does not fit its type (naming the field).
            RuntimeError: the publisher or its participant was closed.
        """
        writer = self._live()
        if type(message) is not self.msg_type:
            raise ValueError(f"{self.topic} publishes {ros_name(self.msg_type)}, got {type(message).__name__}")
        try:
            writer.write(message)
        except DDSException:
            raise
        except Exception as error:  # cyclonedds wraps a member's error in a bare Exception
            raise ValueError(f"cannot publish on {self.topic}: {field_error(error)}") from error

    def matched_subscriptions(self) -> int:
        """How many readers (ours or a ROS node's) currently receive from this writer."""
        return self._live().get_publication_matched_status().current_count


class Subscription(_Endpoint):
    """A ROS 2 subscription: a DDS reader on ``rt`` + ``topic`` (made by :meth:`RosParticipant.subscription`).

    Counters: ``received`` messages taken, ``dropped`` older messages :meth:`take_newest` discarded, ``malformed``
    samples that did not deserialise (skipped).
    """

    def __init__(self, *args):
        super().__init__(*args)
        self.received = self.dropped = self.malformed = 0
        self.condition = None

    def _take_raw(self) -> list:
        reader = self._live()
        samples = []
        while True:
            batch = ddspy_take(reader._ref, _ANY, max(self.qos.depth, 16))
            if isinstance(batch, int):
                raise DDSException(batch, f"taking from {self.topic}")
            samples += [(data, info) for data, info in batch if info.valid_data]
            if len(batch) < max(self.qos.depth, 16):
                return samples

    def _decode(self, data, info):
        try:
            message = self.msg_type.deserialize(data)
        except Exception:
            self.malformed += 1
            return None
        return message, MessageInfo(info.source_timestamp * 1e-9, info.publication_handle)

    def take(self) -> list:
        """Every message received since the last take, oldest first, as ``(message, MessageInfo)``: at most the QoS
        depth of them (a keep-last reader overwrites older ones). Never blocks."""
        out = [pair for pair in (self._decode(*sample) for sample in self._take_raw()) if pair is not None]
        self.received += len(out)
        return out

    def take_newest(self):
        """The newest message received since the last take, or None; older ones are dropped (counted in
        ``dropped``) without being deserialised. Never blocks."""
        samples = self._take_raw()
        while samples:
            decoded = self._decode(*samples.pop())
            if decoded is not None:
                self.received += 1
                self.dropped += len(samples)
                return decoded[0]
        return None

    def matched_publishers(self) -> int:
        """How many writers (ours or a ROS node's) this reader currently receives from."""
        return self._live().get_subscription_matched_status().current_count

    def incompatible_qos(self) -> int:
        """How many times a writer on this topic was refused for incompatible QoS (e.g. a best-effort writer and
        this reliable reader: :mod:`superex_deploy.ros.qos`). Nonzero means data this reader will never get."""
        return self._live().get_requested_incompatible_qos_status().total_count


_DOMAINS: dict = {}  # domain id -> [Domain, config, participants]
_DOMAINS_LOCK = threading.Lock()


class RosParticipant:
    """A ROS 2 node's view of DDS: one participant on domain ``domain_id`` (None: ``ROS_DOMAIN_ID``, default 0).

    Args:
        node_name: the node's name (letters, digits, ``_``; not starting with a digit).
        namespace: the node's namespace (``""`` or ``"/"``: the root; ``"robot1"`` means ``"/robot1"``).
        domain_id: 0..232; None reads ``ROS_DOMAIN_ID``.
        config: a Cyclone DDS XML configuration for this domain (e.g. :func:`loopback_config`); None: Cyclone's
            default or ``CYCLONEDDS_URI``. Participants of one process share a domain's configuration.
        discovery_info: publish ``ros_discovery_info`` so that ``ros2 node list`` (Iron and later) shows the node.

    Raises:
        ValueError: an invalid node name, namespace or domain id (or ``ROS_DOMAIN_ID``), or a ``config`` that differs
            from the one this process already uses for the domain.
    """

    def __init__(self, node_name: str, namespace: str = "", domain_id: Optional[int] = None,
                 config: Optional[str] = None, discovery_info: bool = True):
        if not isinstance(node_name, str) or not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]{0,254}", node_name):
            raise ValueError(f"invalid ROS 2 node name {node_name!r}: letters, digits and '_', not starting with a "
                             "digit, at most 255 characters")
        if not isinstance(namespace, str):
            raise ValueError(f"the namespace must be a string, got {namespace!r}")
        ns = "/" + namespace.strip("/") if namespace.strip("/") else "/"
        if ns != "/":
            _check_name(ns, "namespace", namespace, _MAX_TOPIC_LENGTH - 2)  # RMW_NAMESPACE_MAX_LENGTH
        self.node_name, self.namespace, self.domain_id = node_name, ns, _domain_id(domain_id)
        self.closed = False
        self._lock = threading.RLock()
        self._endpoints: list = []
        self._topics: dict = {}
        self._waitsets: dict = {}
        self._domain = self._join_domain(config)
        self._dp = None
        try:
            self._dp = DomainParticipant(self.domain_id, qos=Qos(Policy.Userdata(data=b"enclave=/;")))
            self._guard = GuardCondition(self._dp)
            self._discovery = None
            if discovery_info:
                topic = Topic(self._dp, DISCOVERY_TOPIC, ParticipantEntitiesInfo)
                self._discovery = DataWriter(self._dp, topic, DISCOVERY_INFO.to_dds(
                    f"typehash={type_hash(ParticipantEntitiesInfo)};".encode()))
                self._publish_graph()
        except BaseException:
            if self._dp is not None:
                self._dp.__del__()
            self._leave_domain()
            raise

    @property
    def gid(self) -> bytes:
        """The participant's 16-byte DDS GUID."""
        return self._dp.guid.bytes

    def _join_domain(self, config):
        if config is None:
            return None
        with _DOMAINS_LOCK:
            entry = _DOMAINS.get(self.domain_id)
            if entry is None:
                try:
                    entry = _DOMAINS[self.domain_id] = [Domain(self.domain_id, config), config, 0]
                except DDSException as error:
                    if error.code == DDSException.DDS_RETCODE_PRECONDITION_NOT_MET:
                        raise ValueError(f"domain {self.domain_id} already runs in this process with its default "
                                         "configuration") from error
                    raise ValueError(f"Cyclone DDS refused the configuration for domain {self.domain_id} (an "
                                     f"interface that is down or missing? Cyclone's log says more): {error}") from error
            elif entry[1] != config:
                raise ValueError(f"domain {self.domain_id} already runs in this process with another configuration")
            entry[2] += 1
            return entry

    def _leave_domain(self) -> None:
        if self._domain is None:
            return
        with _DOMAINS_LOCK:
            self._domain[2] -= 1
            # Deleting a domain deletes every participant in it: keep it while another (not ours) lives there.
            if self._domain[2] == 0 and not self._domain[0].get_participants():
                del _DOMAINS[self.domain_id]
                self._domain[0].__del__()
        self._domain = None

    def resolve(self, topic: str) -> str:
        """The fully qualified ROS 2 name of ``topic``: ``"/map"`` stays, ``"map"`` -> ``"/<ns>/map"``, ``"~/x"`` ->
        ``"/<ns>/<node>/x"`` (``"~"`` alone: the node's own name).

        Raises:
            ValueError: an invalid name (ROS 2's rules), naming it.
        """
        if not isinstance(topic, str) or not topic:
            raise ValueError(f"invalid ROS 2 topic name {topic!r}: it must be a non-empty string")
        base = self.namespace.rstrip("/")
        if topic == "~" or topic.startswith("~/"):
            full = f"{base}/{self.node_name}{topic[1:]}"
        elif topic.startswith("/"):
            full = topic
        else:
            full = f"{base}/{topic}"
        if full.endswith("/"):
            raise ValueError(f"invalid ROS 2 topic name {topic!r}: it must not end with '/'")
        _check_name(full, "topic name", topic)
        return full

    def _topic(self, name: str, msg_type):
        if msg_type not in MESSAGE_TYPES.values():
            raise ValueError(f"not a ROS message class of this package: {msg_type!r}")
        known = self._topics.get(name)
        if known is not None and known.data_type is not msg_type:
            raise ValueError(f"{name} already carries {ros_name(known.data_type)} in this participant, "
                             f"not {ros_name(msg_type)}")
        if known is None:
            known = self._topics[name] = Topic(self._dp, "rt" + name, msg_type)
        return known

    def _add(self, endpoint, make):
        if not isinstance(endpoint.qos, RosQos):
            raise ValueError(f"qos must be a RosQos (superex_deploy.ros.qos), got {endpoint.qos!r}")
        with self._lock:
            self._check_open()
            topic = self._topic(endpoint.topic, endpoint.msg_type)
            user_data = f"typehash={type_hash(endpoint.msg_type)};".encode()
            endpoint.entity = make(self._dp, topic, endpoint.qos.to_dds(user_data))
            self._endpoints.append(endpoint)
            self._publish_graph()
        return endpoint

    def publisher(self, topic: str, msg_type, qos: RosQos) -> Publisher:
        """A publisher of ``msg_type`` messages (a class of ``idl.MESSAGE_TYPES``) on ``topic`` (resolved).

        Raises:
            ValueError: an invalid topic, an unknown message class, a topic this participant already uses with another
                type, or ``qos`` not a :class:`RosQos`.
        """
        return self._add(Publisher(self, self.resolve(topic), msg_type, qos), DataWriter)

    def subscription(self, topic: str, msg_type, qos: RosQos) -> Subscription:
        """A subscription to ``msg_type`` messages on ``topic`` (resolved); read it with ``take`` / ``take_newest``.

        Raises:
            ValueError: as :meth:`publisher`.
        """
        subscription = self._add(Subscription(self, self.resolve(topic), msg_type, qos), DataReader)
        subscription.condition = ReadCondition(subscription.entity, _ANY)
        return subscription

    def wait(self, subscriptions, timeout_s: float) -> bool:
        """Block until one of ``subscriptions`` has data to take, ``timeout_s`` seconds pass or :meth:`wake` is
        called; True when there is something to take (possibly only DDS's notice that a writer left, which ``take``
        skips: the loop then finds nothing). For one loop thread at a time.

        Raises:
            ValueError: ``timeout_s`` negative or not finite (an infinite wait could hang), or a subscription of
                another participant.
            RuntimeError: the participant or a subscription was closed.
        """
        if not isinstance(timeout_s, (int, float)) or not math.isfinite(timeout_s) or timeout_s < 0:
            raise ValueError(f"timeout_s must be a finite number of seconds >= 0, got {timeout_s!r}")
        subscriptions = list(subscriptions)
        for subscription in subscriptions:
            if not isinstance(subscription, Subscription) or subscription.participant is not self:
                raise ValueError(f"{subscription!r} is not a subscription of this participant")
            subscription._live()
        with self._lock:
            self._check_open()
            key = tuple(sorted(id(s) for s in subscriptions))
            waitset = self._waitsets.get(key)
            if waitset is None:
                waitset = self._waitsets[key] = WaitSet(self._dp)
                waitset.attach(self._guard)
                for subscription in subscriptions:
                    waitset.attach(subscription.condition)
        waitset.wait(int(min(timeout_s, 1e9) * 1e9))
        self._guard.set(False)
        return any(s.entity is not None and s.condition.triggered for s in subscriptions)

    def wake(self) -> None:
        """Make a :meth:`wait` in another thread return now (e.g. to shut down); nothing once closed."""
        with self._lock:
            if not self.closed:
                self._guard.set(True)

    def _forget(self, endpoint) -> None:
        with self._lock:
            self._endpoints.remove(endpoint)
            self._waitsets = {k: w for k, w in self._waitsets.items() if id(endpoint) not in k}
            self._publish_graph()

    def _publish_graph(self) -> None:
        if self._discovery is None or self.closed:
            return
        readers = [Gid(e.entity.guid.bytes) for e in self._endpoints if isinstance(e, Subscription)]
        writers = [Gid(e.entity.guid.bytes) for e in self._endpoints if isinstance(e, Publisher)]
        node = NodeEntitiesInfo(self.namespace, self.node_name, readers, writers)
        self._discovery.write(ParticipantEntitiesInfo(Gid(self.gid), [node]))

    def _check_open(self) -> None:
        if self.closed:
            raise RuntimeError(f"the participant of node {self.node_name} was closed")

    def close(self) -> None:
        """Tell the ROS graph the node is gone, then delete the participant and everything in it. Idempotent."""
        with self._lock:
            if self.closed:
                return
            if self._discovery is not None:
                self._discovery.write(ParticipantEntitiesInfo(Gid(self.gid), []))
            self.closed = True
            for endpoint in self._endpoints:
                endpoint.entity = None
            self._endpoints, self._waitsets, self._topics = [], {}, {}
            self._dp.__del__()  # deletes the readers, writers, topics and wait sets with it
            self._leave_domain()

    def __enter__(self) -> "RosParticipant":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

"""The ROS 2 wire layer (``superex_deploy.ros``): every message byte-identical to rosbags' ROS 2 CDR with random
values, the numpy fast path, the QoS rules, name resolution, the type hash in USER_DATA as a second participant sees
it, ``ros_discovery_info``, and two processes over the loopback (a late-joining map reader, a refused best-effort
writer). Every wait has a timeout; the participants use :func:`loopback_config`, so no network is needed."""

import dataclasses
import os
import subprocess
import sys
import textwrap
import threading
import time
import zlib

import numpy as np
import pytest

pytest.importorskip("cyclonedds")
pytest.importorskip("rosbags")

from cyclonedds.builtin import BuiltinDataReader, BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription  # noqa: E402
from cyclonedds.core import Policy  # noqa: E402
from cyclonedds.domain import DomainParticipant  # noqa: E402
from cyclonedds.idl._support import Endianness  # noqa: E402
from cyclonedds.sub import DataReader  # noqa: E402
from cyclonedds.topic import Topic  # noqa: E402
from rosbags.interfaces import Nodetype  # noqa: E402
from rosbags.typesys import Stores, get_types_from_msg, get_typestore  # noqa: E402

from superex_deploy.ros import dds, discovery, idl, qos  # noqa: E402

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
CONFIG = dds.loopback_config()
DOMAIN = os.getpid() % 200 + 20
ALL_TYPES = {**idl.MESSAGE_TYPES, **{idl.ros_name(c): c for c in (discovery.Gid, discovery.NodeEntitiesInfo,
                                                                   discovery.ParticipantEntitiesInfo)}}


def _store():
    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(idl.SPAD_FRAME_MSG, "superex_msgs/msg/SpadFrame"))
    store.register(get_types_from_msg(idl.EXPLORER_STATUS_MSG, "superex_msgs/msg/ExplorerStatus"))
    return store


STORE = _store()
NUMPY = {"int8": np.int8, "uint8": np.uint8, "char": np.uint8, "int16": np.int16, "uint16": np.uint16,
         "int32": np.int32, "uint32": np.uint32, "int64": np.int64, "uint64": np.uint64, "float32": np.float32,
         "float64": np.float64}
STRINGS = ["", "map", "base_link", "ü→雪 ✓ \U0001F916", "x" * 300, "tab\tand\nnewline"]


def _number(typ: str, rng):
    """A random value of a ROS number type: often an extreme (min, max, 0, NaN, +-inf, subnormal)."""
    if typ == "bool":
        return bool(rng.integers(2))
    dtype = np.dtype(NUMPY[typ])
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        return int(rng.choice([info.min, info.max, 0, int(rng.integers(info.min, info.max, dtype=dtype))]))
    info = np.finfo(dtype)
    pick = rng.integers(8)
    value = [np.nan, np.inf, -np.inf, -0.0, float(info.max), float(info.smallest_subnormal), float(info.tiny),
             float(rng.normal() * 1e3)][pick]
    return float(dtype.type(value))


def _array(typ: str, length: int, rng) -> np.ndarray:
    return np.array([_number(typ, rng) for _ in range(length)], NUMPY[typ])


def _random(node, rng):
    """A random value for a rosbags field node: a tree of ("msg", name, {field: value}), numbers, strings, arrays."""
    kind, arg = node
    if kind == Nodetype.BASE:
        typ, bound = arg
        if typ == "string":
            text = STRINGS[rng.integers(len(STRINGS))]
            return text[:bound] if bound else text
        return _number(typ, rng)
    if kind == Nodetype.NAME:
        return _random_message(arg, rng)
    sub, size = arg
    length = size if kind == Nodetype.ARRAY else int(rng.choice([0, 1, rng.integers(2, 40)]))
    if sub[0] == Nodetype.BASE and sub[1][0] in NUMPY:
        return _array(sub[1][0], length, rng)
    return [_random(sub, rng) for _ in range(length)]


def _random_message(name: str, rng):
    return ("msg", name, {field: _random(node, rng) for field, node in STORE.fielddefs[name][1]})


def _to_rosbags(value):
    if isinstance(value, tuple) and value[:1] == ("msg",):
        return STORE.types[value[1]](**{k: _to_rosbags(v) for k, v in value[2].items()})
    if isinstance(value, list):
        return [_to_rosbags(v) for v in value]
    return value


def _to_cyclone(value):
    if isinstance(value, tuple) and value[:1] == ("msg",):
        fields = {k: _to_cyclone(v) for k, v in value[2].items()}
        if value[1] == "rmw_dds_common/msg/Gid":
            fields["data"] = fields["data"].tobytes()
        return ALL_TYPES[value[1]](**fields)
    if isinstance(value, list):
        return [_to_cyclone(v) for v in value]
    return value


def _assert_same(tree, decoded, where: str):
    """``decoded`` (a cyclonedds message) holds the values of ``tree``, dtypes included, NaN equal to NaN."""
    if isinstance(tree, tuple) and tree[:1] == ("msg",):
        assert type(decoded) is ALL_TYPES[tree[1]], where
        for key, value in tree[2].items():
            _assert_same(value, getattr(decoded, key), f"{where}.{key}")
    elif isinstance(tree, list):
        assert isinstance(decoded, list) and len(decoded) == len(tree), where
        for i, (a, b) in enumerate(zip(tree, decoded)):
            _assert_same(a, b, f"{where}[{i}]")
    elif isinstance(tree, np.ndarray):
        if isinstance(decoded, bytes):  # a Gid
            assert decoded == tree.tobytes(), where
        else:
            assert isinstance(decoded, np.ndarray) and decoded.dtype == tree.dtype, (where, decoded)
            assert decoded.flags.writeable, where
            np.testing.assert_array_equal(decoded, tree, err_msg=where)
    elif isinstance(tree, float):
        assert (np.isnan(tree) and np.isnan(decoded)) or (tree == decoded and
                                                          np.signbit(tree) == np.signbit(decoded)), where
    else:
        assert tree == decoded and type(tree) is type(decoded), (where, tree, decoded)


@pytest.mark.parametrize("name", sorted(ALL_TYPES))
def test_every_message_is_byte_identical_to_rosbags(name):
    cls = ALL_TYPES[name]
    package, _, base = name.split("/")
    assert cls.__idl_typename__ == f"{package}::msg::dds_::{base}_" == idl.dds_type_name(name)
    assert idl.ros_name(cls) == name
    assert [f.name for f in dataclasses.fields(cls)] == [f for f, _ in STORE.fielddefs[name][1]]
    rng = np.random.default_rng(zlib.crc32(name.encode()))
    for trial in range(12):
        tree = _random_message(name, rng)
        expected = bytes(STORE.serialize_cdr(_to_rosbags(tree), name))
        message = _to_cyclone(tree)
        assert message.serialize() == expected, (name, trial)
        _assert_same(tree, cls.deserialize(expected), name)
        big = bytes(STORE.serialize_cdr(_to_rosbags(tree), name, little_endian=False))
        assert message.serialize(endianness=Endianness.Big) == big, (name, trial)
        _assert_same(tree, cls.deserialize(big), name)
    if name in idl.MESSAGE_TYPES:
        _assert_same(tree, idl.from_cdr(cls, idl.to_cdr(message)), name)


def test_humble_and_jazzy_markers_have_the_same_fields():
    humble, jazzy = get_typestore(Stores.ROS2_HUMBLE), get_typestore(Stores.ROS2_JAZZY)
    name = "visualization_msgs/msg/Marker"
    assert humble.fielddefs[name][1] == jazzy.fielddefs[name][1]
    assert idl.Marker.ARROW_STRIP == 12 and idl.Marker.DELETEALL == 3


def test_numeric_arrays_use_the_numpy_machines_and_are_fast():
    assert idl.FAST_FIELDS["nav_msgs/msg/OccupancyGrid"] == 2 and idl.FAST_FIELDS["sensor_msgs/msg/LaserScan"] == 4
    grid = idl.OccupancyGrid(info=idl.MapMetaData(resolution=0.0625, width=2000, height=2000),
                             data=np.random.default_rng(0).integers(-1, 101, 4_000_000).astype(np.int8))
    times = []
    for _ in range(3):
        start = time.perf_counter()
        data = grid.serialize()
        middle = time.perf_counter()
        back = idl.OccupancyGrid.deserialize(data)
        times.append((middle - start, time.perf_counter() - middle))
    best = min(times, key=sum)
    print(f"4 M-cell OccupancyGrid: serialize {best[0] * 1e3:.1f} ms, deserialize {best[1] * 1e3:.1f} ms")
    assert sum(best) < 0.2  # the stock cyclonedds machines take ~0.3 s (plus a tolist) on the 2-core machine
    assert back == grid and back.data.dtype == np.int8
    assert len(data) == len(idl.to_cdr(idl.OccupancyGrid(info=grid.info))) + 4_000_000


def test_numeric_fields_accept_what_fits_and_refuse_the_rest():
    scan = idl.LaserScan(ranges=[1.0, 2.5], intensities=np.array([1, 2], np.int64))
    back = idl.from_cdr(idl.LaserScan, idl.to_cdr(scan))
    assert back.ranges.dtype == np.float32 and back.ranges.tolist() == [1.0, 2.5] and back.intensities.tolist() == [1, 2]
    grid = idl.OccupancyGrid(data=np.array([-1, 0, 100], np.int64))
    assert idl.from_cdr(idl.OccupancyGrid, idl.to_cdr(grid)).data.tolist() == [-1, 0, 100]
    assert idl.from_cdr(idl.CompressedImage, idl.to_cdr(idl.CompressedImage(data=b"\x00\xff"))).data.tolist() == [0, 255]
    for bad, field in [(idl.OccupancyGrid(data=[1, 200]), "data"), (idl.OccupancyGrid(data=[0.5]), "data"),
                       (idl.LaserScan(ranges=np.zeros((2, 2))), "ranges"), (idl.LaserScan(ranges=["a"]), "ranges"),
                       (idl.PoseWithCovariance(covariance=np.zeros(35)), "covariance"),
                       (idl.Odometry(pose=idl.PoseWithCovariance(covariance=[0] * 37)), "pose.covariance"),
                       (idl.MapMetaData(width=-1), "width"), (idl.Header(frame_id=3), "frame_id")]:
        with pytest.raises(ValueError, match=f"field {field}: "):
            idl.to_cdr(bad)
    with pytest.raises(ValueError, match="not a ROS message"):
        idl.to_cdr(object())


def test_from_cdr_refuses_truncated_and_foreign_data():
    data = idl.to_cdr(idl.LaserScan(ranges=np.ones(10, np.float32)))
    for bad in (b"", data[:2], b"\x00\x07\x00\x00" + data[4:], data[:-8]):
        with pytest.raises(ValueError):
            idl.from_cdr(idl.LaserScan, bad)
    with pytest.raises(ValueError):
        idl.from_cdr(int, data)


def test_message_equality_compares_arrays_by_value():
    a, b = idl.LaserScan(ranges=np.ones(3, np.float32)), idl.LaserScan(ranges=[1.0, 1.0, 1.0])
    assert a == b and not (a != b)
    assert a != idl.LaserScan(ranges=np.ones(4, np.float32)) and a != idl.LaserScan(ranges=np.zeros(3, np.float32))
    assert idl.Time(1, 2) != idl.Duration(1, 2)


def test_numpy_and_time_helpers():
    values = np.arange(-1, 11).reshape(3, 4)
    grid = idl.OccupancyGrid(info=idl.MapMetaData(width=4, height=3), data=idl.grid_data(values))
    np.testing.assert_array_equal(idl.grid_array(grid), values)
    assert idl.grid_array(grid).dtype == np.int8
    for bad in (np.zeros(4, int), np.zeros((2, 2)), np.full((2, 2), 101), np.full((2, 2), -2)):
        with pytest.raises(ValueError):
            idl.grid_data(bad)
    with pytest.raises(ValueError, match="4 x 3"):
        idl.grid_array(idl.OccupancyGrid(info=idl.MapMetaData(width=4, height=3), data=np.zeros(11, np.int8)))
    assert idl.ranges_array(idl.LaserScan(ranges=[1, 2])).dtype == np.float32
    cov = idl.PoseWithCovariance(covariance=np.arange(36.0))
    assert idl.covariance_matrix(cov)[1, 0] == 6.0
    assert idl.time_from_seconds(1.5) == idl.Time(1, 500_000_000)
    assert idl.time_from_seconds(1.3).nanosec == 300_000_000 and idl.seconds(idl.Time(2, 250_000_000)) == 2.25
    for bad in (-1e-3, float("nan"), 2.0 ** 31, float("inf")):
        with pytest.raises(ValueError):
            idl.time_from_seconds(bad)


def test_importing_the_package_does_not_import_cyclonedds():
    code = ("import sys, superex_deploy.ros, superex_deploy.ros.qos as q; q.MAP.matches(q.MAP); "
            "assert 'cyclonedds' not in sys.modules, 'imported'")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert result.returncode == 0, result.stderr


# --- QoS --------------------------------------------------------------------------------------------------------

def test_profiles_match_the_ros_publishers():
    assert qos.SENSOR_DATA == qos.RosQos("best_effort", "volatile", 5)
    assert qos.MAP == qos.RosQos("reliable", "transient_local", 1)
    assert qos.DEFAULT == qos.RosQos("reliable", "volatile", 10)
    assert qos.TF == qos.RosQos("reliable", "volatile", 100)
    assert qos.TF_STATIC == qos.RosQos("reliable", "transient_local", 1)
    assert qos.CLOCK == qos.RosQos("best_effort", "volatile", 1)
    # The documented matching rule, reader (rows) against writer.
    assert not qos.DEFAULT.matches(qos.SENSOR_DATA) and qos.SENSOR_DATA.matches(qos.DEFAULT)
    assert not qos.MAP.matches(qos.DEFAULT) and qos.DEFAULT.matches(qos.MAP) and qos.MAP.matches(qos.TF_STATIC)
    dds_qos = qos.MAP.to_dds(b"typehash=x;")
    assert dds_qos[Policy.Durability] == Policy.Durability.TransientLocal
    assert dds_qos[Policy.History] == Policy.History.KeepLast(1)
    assert dds_qos[Policy.Userdata] == Policy.Userdata(b"typehash=x;")
    assert qos.SENSOR_DATA.to_dds()[Policy.Reliability] == Policy.Reliability.BestEffort
    for bad in [("reliable", "volatile", 0), ("sometimes", "volatile", 1), ("reliable", "transient", 1),
                ("reliable", "volatile", 1.0), ("reliable", "volatile", True)]:
        with pytest.raises(ValueError):
            qos.RosQos(*bad)


# --- Participant ------------------------------------------------------------------------------------------------

def _until(condition, timeout_s: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def test_name_resolution_follows_ros2(monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN))
    with dds.RosParticipant("explorer", "robot1", config=CONFIG, discovery_info=False) as node:
        assert node.domain_id == DOMAIN and node.namespace == "/robot1"
        assert node.resolve("/map") == "/map" and node.resolve("map") == "/robot1/map"
        assert node.resolve("a/b_2") == "/robot1/a/b_2" and node.resolve("~/status") == "/robot1/explorer/status"
        assert node.resolve("~") == "/robot1/explorer"
        for bad in ["", "/", "map/", "//map", "/a//b", "2map", "/a/2b", "a b", "~x", "a~", "{node}/x", "/map-2",
                    "/" + "a" * 247, 5]:
            with pytest.raises(ValueError, match="topic name"):
                node.resolve(bad)
    with dds.RosParticipant("n", "/", config=CONFIG, discovery_info=False) as root:
        assert root.resolve("scan") == "/scan" and root.resolve("~/x") == "/n/x"


def test_bad_names_and_domains_are_refused(monkeypatch):
    for name in ("", "2node", "my-node", "a/b", "x" * 256):
        with pytest.raises(ValueError, match="node name"):
            dds.RosParticipant(name, domain_id=DOMAIN)
    for namespace in ("/a//b", "/2a", "a-b"):
        with pytest.raises(ValueError, match="namespace"):
            dds.RosParticipant("n", namespace, domain_id=DOMAIN)
    for domain in (-1, 233, 1.0, True, "3"):
        with pytest.raises(ValueError, match="domain_id"):
            dds.RosParticipant("n", domain_id=domain)
    for text in ("abc", "-1", "233", "1.5"):
        monkeypatch.setenv("ROS_DOMAIN_ID", text)
        with pytest.raises(ValueError, match="ROS_DOMAIN_ID"):
            dds.RosParticipant("n")
    monkeypatch.setenv("ROS_DOMAIN_ID", "")
    assert dds._domain_id(None) == 0
    with dds.RosParticipant("n", domain_id=DOMAIN, config=CONFIG, discovery_info=False):
        with pytest.raises(ValueError, match="another configuration"):
            dds.RosParticipant("m", domain_id=DOMAIN, config=CONFIG.replace("32", "31"))
    plain = DomainParticipant(DOMAIN + 1)  # this process's domain DOMAIN + 1 now runs the default configuration
    with pytest.raises(ValueError, match="default configuration"):
        dds.RosParticipant("n", domain_id=DOMAIN + 1, config=CONFIG)
    del plain
    with pytest.raises(ValueError, match="refused the configuration"):
        dds.RosParticipant("n", domain_id=DOMAIN + 2, config=CONFIG.replace('address="127.0.0.1"', 'name="nope0"'))
    assert DOMAIN + 2 not in dds._DOMAINS


def test_known_type_hashes():
    type_hash = discovery.type_hash
    assert type_hash(idl.String) == "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
    assert type_hash(idl.LaserScan) == "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828"
    assert type_hash(idl.SpadFrame) == STORE.hash_rihs01("superex_msgs/msg/SpadFrame")
    with pytest.raises(ValueError):
        type_hash(int)


def test_endpoints_carry_ros_names_and_the_type_hash_in_user_data():
    with dds.RosParticipant("talker", "robot1", domain_id=DOMAIN, config=CONFIG) as node:
        publisher = node.publisher("scan", idl.LaserScan, qos.SENSOR_DATA)
        subscription = node.subscription("/map", idl.OccupancyGrid, qos.MAP)
        observer = DomainParticipant(DOMAIN)
        readers = [BuiltinDataReader(observer, builtin)
                   for builtin in (BuiltinTopicDcpsPublication, BuiltinTopicDcpsSubscription)]
        seen = {}
        assert _until(lambda: seen.update({s.topic_name: s for r in readers for s in r.take(100)})
                      or {"rt/robot1/scan", "rt/map", "ros_discovery_info"} <= set(seen))
        scan, grid = seen["rt/robot1/scan"], seen["rt/map"]
        assert scan.type_name == "sensor_msgs::msg::dds_::LaserScan_" and scan.key.bytes == publisher.gid
        assert scan.qos[Policy.Userdata].data == f"typehash={discovery.type_hash(idl.LaserScan)};".encode()
        assert scan.qos[Policy.Reliability] == Policy.Reliability.BestEffort
        assert grid.type_name == "nav_msgs::msg::dds_::OccupancyGrid_" and grid.key.bytes == subscription.gid
        assert grid.qos[Policy.Userdata].data == f"typehash={discovery.type_hash(idl.OccupancyGrid)};".encode()
        assert grid.qos[Policy.Durability] == Policy.Durability.TransientLocal
        info = seen["ros_discovery_info"]
        assert info.type_name == "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"
        info_hash = discovery.type_hash(discovery.ParticipantEntitiesInfo)
        assert info.qos[Policy.Userdata].data == f"typehash={info_hash};".encode()
        del readers, observer


def test_ros_discovery_info_lists_the_node_and_its_endpoints():
    with dds.RosParticipant("explorer", "robot1", domain_id=DOMAIN, config=CONFIG) as node:
        publisher = node.publisher("goal", idl.PoseStamped, qos.DEFAULT)
        subscription = node.subscription("scan", idl.LaserScan, qos.SENSOR_DATA)
        observer = DomainParticipant(DOMAIN)
        reader = DataReader(observer, Topic(observer, discovery.DISCOVERY_TOPIC, discovery.ParticipantEntitiesInfo),
                            qos.DISCOVERY_INFO.to_dds())  # a late reader: the info is transient local
        newest = [None]

        def newest_is(condition):
            def check():
                taken = reader.take(10)
                newest[0] = taken[-1] if taken else newest[0]
                return newest[0] is not None and condition(newest[0].node_entities_info_seq)
            return _until(check)
        assert newest_is(lambda nodes: nodes and nodes[0].writer_gid_seq and nodes[0].reader_gid_seq)
        info = newest[0]
        assert info.gid.data == node.gid
        (entry,) = info.node_entities_info_seq
        assert (entry.node_namespace, entry.node_name) == ("/robot1", "explorer")
        assert [g.data for g in entry.writer_gid_seq] == [publisher.gid]
        assert [g.data for g in entry.reader_gid_seq] == [subscription.gid]
        publisher.close()
        assert newest_is(lambda nodes: nodes and not nodes[0].writer_gid_seq and nodes[0].reader_gid_seq)
        with pytest.raises(RuntimeError, match="closed"):
            publisher.publish(idl.PoseStamped())
        node.close()
        assert newest_is(lambda nodes: nodes == [])
        del reader, observer


def test_publish_take_wait_and_close():
    with dds.RosParticipant("a", domain_id=DOMAIN, config=CONFIG) as a, \
            dds.RosParticipant("b", domain_id=DOMAIN, config=CONFIG) as b:
        publisher = a.publisher("/scan", idl.LaserScan, qos.SENSOR_DATA)
        subscription = b.subscription("/scan", idl.LaserScan, qos.SENSOR_DATA)
        assert _until(lambda: publisher.matched_subscriptions() == 1 and subscription.matched_publishers() == 1)
        start = time.monotonic()
        assert not b.wait([subscription], 0.2) and 0.15 < time.monotonic() - start < 2.0
        for i in range(4):
            publisher.publish(idl.LaserScan(header=idl.Header(frame_id=f"f{i}"), ranges=np.full(3, i, np.float32)))
        assert b.wait([subscription], 5.0)
        assert _until(lambda: len(subscription.entity.read(10)) == 4)
        latest = subscription.take_newest()
        assert latest.header.frame_id == "f3" and latest.ranges.tolist() == [3.0] * 3
        assert (subscription.received, subscription.dropped, subscription.malformed) == (1, 3, 0)
        assert subscription.take_newest() is None and subscription.take() == []
        publisher.publish(idl.LaserScan(ranges=[1.0]))
        assert _until(lambda: len(subscription.entity.read(10)) == 1)
        ((message, info),) = subscription.take()
        assert message.ranges.tolist() == [1.0] and abs(info.source_time_s - time.time()) < 30
        with pytest.raises(ValueError, match="publishes sensor_msgs/msg/LaserScan"):
            publisher.publish(idl.OccupancyGrid())
        with pytest.raises(ValueError, match="field ranges"):
            publisher.publish(idl.LaserScan(ranges=["x"]))
        with pytest.raises(ValueError, match="already carries"):
            a.subscription("/scan", idl.OccupancyGrid, qos.MAP)
        with pytest.raises(ValueError, match="RosQos"):
            a.publisher("/x", idl.String, "reliable")
        with pytest.raises(ValueError, match="timeout_s"):
            b.wait([subscription], float("inf"))
        with pytest.raises(ValueError, match="not a subscription of this participant"):
            a.wait([subscription], 0.0)
        waker = threading.Timer(0.2, b.wake)
        waker.start()
        start = time.monotonic()
        assert not b.wait([subscription], 20.0) and time.monotonic() - start < 10.0
        b.close()
        with pytest.raises(RuntimeError, match="closed"):
            subscription.take()
        with pytest.raises(RuntimeError, match="closed"):
            b.publisher("/y", idl.String, qos.DEFAULT)


def test_incompatible_qos_is_not_matched_in_process():
    with dds.RosParticipant("w", domain_id=DOMAIN, config=CONFIG, discovery_info=False) as writer_node, \
            dds.RosParticipant("r", domain_id=DOMAIN, config=CONFIG, discovery_info=False) as reader_node:
        writer_node.publisher("/volatile", idl.String, qos.DEFAULT)
        late = reader_node.subscription("/volatile", idl.String, qos.MAP)      # transient local reader
        ok = reader_node.subscription("/volatile", idl.String, qos.DEFAULT)
        assert _until(lambda: ok.matched_publishers() == 1 and late.incompatible_qos() >= 1)
        assert late.matched_publishers() == 0


# --- Two processes over the loopback ----------------------------------------------------------------------------

CHILD = textwrap.dedent("""
    import sys, threading, time
    import numpy as np
    from superex_deploy.ros import dds, idl, qos
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    with dds.RosParticipant("robot_sim", domain_id=int(sys.argv[1])) as node:
        grid_pub = node.publisher("/map", idl.OccupancyGrid, qos.MAP)
        scan_pub = node.publisher("/scan", idl.LaserScan, qos.SENSOR_DATA)
        be_pub = node.publisher("/chatter", idl.String, qos.SENSOR_DATA)
        grid_pub.publish(idl.OccupancyGrid(header=idl.Header(frame_id="map"), info=idl.MapMetaData(
            resolution=0.05, width=300, height=200), data=np.tile(np.arange(-1, 101, dtype=np.int8), 600)[:60000]))
        print("ready", flush=True)
        deadline, i = time.monotonic() + 60, 0
        while not stop.is_set() and time.monotonic() < deadline:
            scan_pub.publish(idl.LaserScan(header=idl.Header(frame_id="laser"), angle_increment=0.0025,
                                           range_max=30.0, ranges=np.full(2500, i, np.float32)))
            be_pub.publish(idl.String(f"hello {i}"))
            i += 1
            time.sleep(0.05)
""")


@pytest.mark.slow
def test_two_processes_late_map_reader_and_refused_best_effort_writer():
    domain = os.getpid() % 200 + 20
    env = {**os.environ, "CYCLONEDDS_URI": CONFIG}
    child = subprocess.Popen([sys.executable, "-c", CHILD, str(domain)], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=ROOT, env=env)
    try:
        ready = []
        reader = threading.Thread(target=lambda: ready.append(child.stdout.readline()), daemon=True)
        reader.start()
        reader.join(60)
        assert ready == ["ready\n"], child.stderr.read() if child.poll() is not None else "no ready line"
        time.sleep(0.5)  # the map was published before this process had any reader
        with dds.RosParticipant("explorer", domain_id=domain, config=CONFIG) as node:
            grid_sub = node.subscription("/map", idl.OccupancyGrid, qos.MAP)
            scan_sub = node.subscription("/scan", idl.LaserScan, qos.SENSOR_DATA)
            reliable = node.subscription("/chatter", idl.String, qos.DEFAULT)
            best_effort = node.subscription("/chatter", idl.String, qos.SENSOR_DATA)
            grids, scans, chatter = [], [], []
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and not (grids and len(scans) >= 3 and chatter):
                node.wait([grid_sub, scan_sub, best_effort], 1.0)
                grids += grid_sub.take()
                scans += scan_sub.take()
                chatter += best_effort.take()
            assert grids and len(scans) >= 3 and chatter
            grid = grids[-1][0]
            assert (grid.info.width, grid.info.height, grid.header.frame_id) == (300, 200, "map")
            np.testing.assert_array_equal(idl.grid_array(grid).ravel(),
                                          np.tile(np.arange(-1, 101, dtype=np.int8), 600)[:60000])
            scan = scans[-1][0]
            assert scan.ranges.shape == (2500,) and scan.ranges.dtype == np.float32 and scan.header.frame_id == "laser"
            assert chatter[-1][0].data.startswith("hello ")
            # The documented rule: a reliable reader does not match a best-effort writer.
            assert reliable.matched_publishers() == 0 and reliable.incompatible_qos() >= 1 and reliable.take() == []
            assert best_effort.matched_publishers() == 1
    finally:
        try:
            child.communicate(input="", timeout=30)
        except subprocess.TimeoutExpired:
            child.kill()
            child.communicate(timeout=30)
    assert child.returncode == 0

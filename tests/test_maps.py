import numpy as np
import pytest
from PIL import Image

from superex_deploy.maps import OccupancyGrid, list_maps, load_map, map_building, start_poses


def test_bundled_splits_are_disjoint_by_map_and_building():
    eval_maps, train_maps = list_maps("eval"), list_maps("train")
    assert len(eval_maps) == 10 and len(train_maps) == 112
    assert not set(eval_maps) & set(train_maps)
    assert not {map_building(m) for m in eval_maps} & {map_building(m) for m in train_maps}


@pytest.mark.parametrize("name", list_maps("eval"))
def test_eval_maps_load_with_free_valid_start_poses(name):
    grid = load_map(name)
    assert grid.occupied.dtype == bool and grid.valid.shape == grid.shape
    assert grid.resolution_m == pytest.approx(0.1)
    poses = start_poses(name)
    assert len(poses) == 4
    for pose in poses:
        assert grid.check_pose(pose) == pose and grid.valid[pose]
    assert 0.0 < grid.occupied.mean() < 0.5


def test_png_pgm_and_ros_yaml_round_trip(tmp_path):
    pixels = np.full((6, 9), 255, np.uint8)
    pixels[0, :] = 0
    pixels[3, 4] = 100  # occupancy (255-100)/255 = 0.61: free at ROS's default 0.65, wall at 0.5
    Image.fromarray(pixels).save(tmp_path / "m.png")
    Image.fromarray(pixels).save(tmp_path / "m.pgm")
    for file in ("m.png", "m.pgm"):
        grid = load_map(tmp_path / file, resolution_m=0.05)
        assert grid.resolution_m == 0.05 and grid.name == "m"
        assert grid.occupied[0].all() and not grid.occupied[3, 4] and grid.occupied.sum() == 9
        np.testing.assert_array_equal(grid.valid, ~grid.occupied)
    (tmp_path / "m.yaml").write_text("image: m.png\nresolution: 0.2\noccupied_thresh: 0.5\nnegate: 0\n")
    grid = load_map(tmp_path / "m.yaml")
    assert grid.resolution_m == 0.2 and grid.occupied[3, 4] and grid.occupied.sum() == 10
    (tmp_path / "n.yaml").write_text("image: m.png\nresolution: 0.2\nnegate: 1\n")
    negated = load_map(tmp_path / "n.yaml")
    # negated, p = v / 255: row 0 free, 255 walls, the 100-pixel (p = 0.39) between the thresholds: unknown,
    # which lies outside the world (an obstacle to the simulator, outside the valid area)
    assert not negated.occupied[0].any() and negated.occupied[1:, :].all()
    assert negated.valid[0].all() and negated.valid.sum() == 9


def _map_server(tmp_path, pixels, **fields) -> "OccupancyGrid":
    Image.fromarray(pixels).save(tmp_path / "f.pgm")
    lines = ["image: f.pgm", "resolution: 0.05"] + [f"{key}: {value}" for key, value in fields.items()]
    (tmp_path / "f.yaml").write_text("\n".join(lines) + "\n")
    return load_map(tmp_path / "f.yaml")


def test_a_map_servers_unknown_cells_lie_outside_the_world(tmp_path):
    # map_saver's trinary output: 254 free, 0 wall, 205 unknown; a building whose door opens onto unknown space
    pixels = np.full((20, 30), 205, np.uint8)
    pixels[5:15, 5:20] = 254
    pixels[5, 5:20] = pixels[14, 5:20] = pixels[5:15, 5] = 0
    pixels[5:15, 19] = 0
    pixels[9:11, 19] = 254  # the door, and the unknown beyond it
    grid = _map_server(tmp_path, pixels, occupied_thresh=0.65, free_thresh=0.196, origin="[-3.0, 1.5, 0.0]")
    unknown = pixels == 205
    assert grid.occupied[unknown].all() and not grid.valid[unknown].any()  # opaque, not traversable, not covered
    assert grid.valid.sum() == np.count_nonzero(pixels == 254)
    assert grid.origin_xy == (-3.0, 1.5)


def test_map_server_modes_and_thresholds(tmp_path):
    pixels = np.array([[0, 60, 100, 101, 255]], np.uint8)
    raw = _map_server(tmp_path, pixels, mode="raw", occupied_thresh=0.65, free_thresh=0.25)
    # raw: p = v / 100 for v <= 100 (0 free, 0.6 unknown, 1.0 wall), unknown above 100
    assert raw.valid.tolist() == [[True, False, False, False, False]]
    assert raw.occupied.tolist() == [[False, True, True, True, True]]
    scale = _map_server(tmp_path, np.array([[0, 100, 200, 255]], np.uint8), mode="scale", free_thresh=0.1)
    # p = (255 - v) / 255 = 1, 0.61, 0.22, 0: wall, unknown, unknown (above free_thresh 0.1), free
    assert scale.valid.tolist() == [[False, False, False, True]]
    for mode in ("banana", 3):
        with pytest.raises(ValueError, match="mode must be one of trinary, scale, raw"):
            _map_server(tmp_path, pixels, mode=mode)
    with pytest.raises(ValueError, match=r"a rotated origin \(yaw 3.14\) is not supported"):
        _map_server(tmp_path, pixels, origin="[0.0, 0.0, 3.14]")
    with pytest.raises(ValueError, match="origin must be three finite numbers"):
        _map_server(tmp_path, pixels, origin="[0.0, 0.0]")
    with pytest.raises(ValueError, match="need 0 <= free_thresh <= occupied_thresh <= 1"):
        _map_server(tmp_path, pixels, free_thresh=0.8, occupied_thresh=0.65)


def test_valid_mask_sibling_is_used(tmp_path):
    Image.fromarray(np.full((4, 4), 255, np.uint8)).save(tmp_path / "a.png")
    valid = np.zeros((4, 4), np.uint8)
    valid[1:3, 1:3] = 255
    Image.fromarray(valid).save(tmp_path / "a_valid.png")
    assert load_map(tmp_path / "a.png").valid.sum() == 4


def test_grid_is_read_only():
    grid = load_map("50052750")
    with pytest.raises(ValueError):
        grid.occupied[0, 0] = True


def test_bad_inputs(tmp_path):
    with pytest.raises(ValueError, match="no bundled map"):
        load_map("no_such_map")
    (tmp_path / "junk.png").write_bytes(b"not a png")
    with pytest.raises(ValueError, match="cannot read image"):
        load_map(tmp_path / "junk.png")
    with pytest.raises(ValueError, match="resolution"):
        Image.fromarray(np.zeros((3, 3), np.uint8)).save(tmp_path / "z.png")
        load_map(tmp_path / "z.png", resolution_m=0.0)
    (tmp_path / "bad.yaml").write_text("image: z.png\nresolution: -1\n")
    with pytest.raises(ValueError, match="resolution must be positive"):
        load_map(tmp_path / "bad.yaml")
    (tmp_path / "missing.yaml").write_text("image: nothere.png\nresolution: 0.1\n")
    with pytest.raises(ValueError, match="does not exist"):
        load_map(tmp_path / "missing.yaml")
    with pytest.raises(ValueError, match="2-D"):
        OccupancyGrid(np.zeros(5, bool), np.zeros(5, bool), 0.1, "x")
    with pytest.raises(ValueError, match="2-D"):
        OccupancyGrid(np.zeros((0, 3), bool), np.zeros((0, 3), bool), 0.1, "x")
    with pytest.raises(ValueError, match="bool"):
        OccupancyGrid(np.zeros((2, 2), np.uint8), np.zeros((2, 2), bool), 0.1, "x")
    with pytest.raises(ValueError, match="split"):
        list_maps("test")
    with pytest.raises(ValueError, match="start poses"):
        start_poses(list_maps("train")[0])
    grid = load_map("50052750")
    with pytest.raises(ValueError, match="outside"):
        grid.check_pose((-1, 3))
    wall = tuple(np.argwhere(grid.occupied)[0])
    with pytest.raises(ValueError, match="inside a wall"):
        grid.check_pose(wall)


@pytest.mark.slow
def test_deploy_package_imports_without_torch():
    """Every superex_deploy module imports with torch made unimportable (a torch install must not be needed)."""
    import subprocess
    import sys

    code = (
        "import sys\n"
        "class _BlockTorch:\n"
        "    def find_spec(self, name, path=None, target=None):\n"
        "        if name == 'torch' or name.startswith('torch.') or name.startswith('superex_train'):\n"
        "            raise ImportError(f'{name} is blocked in this test')\n"
        "sys.meta_path.insert(0, _BlockTorch())\n"
        "import importlib, pkgutil, superex_deploy\n"
        "mods = [m.name for m in pkgutil.walk_packages(superex_deploy.__path__, 'superex_deploy.')]\n"
        "for m in mods: importlib.import_module(m)\n"
        "assert 'torch' not in sys.modules\n"
        "print(len(mods))\n")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert int(result.stdout.strip()) >= 5


def test_a_map_yaml_whose_thresholds_leave_no_free_cell_is_refused(tmp_path):
    # free_thresh 0 ("0 means free"): every pixel unknown, outside the world; a start was then refused as "inside a
    # wall", which named neither the YAML nor its thresholds.
    pixels = np.full((10, 12), 254, np.uint8)
    pixels[0, :] = 0
    with pytest.raises(ValueError, match=r"f.yaml: no pixel is free .*free_thresh 0.0 in trinary mode"):
        _map_server(tmp_path, pixels, free_thresh=0.0)
    with pytest.raises(ValueError, match=r"no pixel is free .*negated"):  # a white map read negated
        _map_server(tmp_path, np.full((10, 12), 254, np.uint8), negate=1)
    assert _map_server(tmp_path, pixels).valid.sum() == 9 * 12

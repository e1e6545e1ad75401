"""DEM loaders (SRTM .hgt, .npz) round trips, bad inputs, and terrain settings."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from testbed.frames import geodetic_to_ecef
from testbed.world.dem import read_hgt
from testbed.world.settings import TerrainSettings, load_terrain
from testbed.world.terrain import Flat, GridTerrain, TwoRidges
from testbed.world.valley import LinZhiSyntheticValley

NODE_TOL_M = 1e-6  # grid nodes: exact up to the float rounding of the node's fractional index
BILINEAR_TOL_M = 1e-3  # between nodes: float32 storage of heights up to ~6000 m


def srtm3_heights(seed: int = 0) -> np.ndarray:
    """A 1201x1201 int16 field in file order (row 0 = north edge): a known pattern."""
    r, c = np.mgrid[0:1201, 0:1201]
    rng = np.random.default_rng(seed)
    return (3000 + 2 * c - r + rng.integers(-50, 50, (1201, 1201))).astype(np.int16)


def write_hgt(path, heights_file_order: np.ndarray) -> None:
    heights_file_order.astype(">i2").tofile(path)


def bilinear_reference(lat_ax, lon_ax, H, lat, lon):
    """Textbook bilinear interpolation on an ascending grid, one point at a time."""
    out = []
    for la, lo in zip(np.ravel(lat), np.ravel(lon)):
        i = min(np.searchsorted(lat_ax, la, "right") - 1, len(lat_ax) - 2)
        j = min(np.searchsorted(lon_ax, lo, "right") - 1, len(lon_ax) - 2)
        u = (la - lat_ax[i]) / (lat_ax[i + 1] - lat_ax[i])
        v = (lo - lon_ax[j]) / (lon_ax[j + 1] - lon_ax[j])
        out.append((1 - u) * (1 - v) * H[i, j] + (1 - u) * v * H[i, j + 1]
                   + u * (1 - v) * H[i + 1, j] + u * v * H[i + 1, j + 1])
    return np.array(out)


def test_hgt_round_trip(tmp_path):
    Hf = srtm3_heights()
    p = tmp_path / "N29E094.hgt"
    write_hgt(p, Hf)
    t = load_terrain(TerrainSettings(kind="dem", dem_paths=["N29E094.hgt"]), tmp_path)
    assert isinstance(t, GridTerrain) and not t.synthetic
    # Nodes: file row r is latitude 30 - r/1200 (north edge first), column c longitude 94 + c/1200.
    rng = np.random.default_rng(1)
    r, c = rng.integers(0, 1201, 300), rng.integers(0, 1201, 300)
    lat, lon = 30.0 - r / 1200.0, 94.0 + c / 1200.0
    np.testing.assert_allclose(t.height(lat, lon), Hf[r, c], atol=NODE_TOL_M, rtol=0)
    assert t.height(30.0, 94.0) == pytest.approx(Hf[0, 0], abs=NODE_TOL_M)  # NW corner
    assert t.height(29.0, 95.0) == pytest.approx(Hf[1200, 1200], abs=NODE_TOL_M)  # SE corner
    # Between nodes: bilinear.
    lat = rng.uniform(29.0, 30.0, 300)
    lon = rng.uniform(94.0, 95.0, 300)
    lat_ax = 29.0 + np.arange(1201) / 1200.0
    lon_ax = 94.0 + np.arange(1201) / 1200.0
    ref = bilinear_reference(lat_ax, lon_ax, Hf[::-1].astype(float), lat, lon)
    np.testing.assert_allclose(t.height(lat, lon), ref, atol=BILINEAR_TOL_M, rtol=0)
    assert np.isnan(t.height(30.01, 94.5))  # outside the tile
    assert t.resolution_m == pytest.approx(3 / 3600 * np.pi / 180 * 6.383e6 * np.cos(np.radians(30)), rel=2e-3)


def test_hgt_voids_are_filled_from_a_neighbour(tmp_path):
    Hf = srtm3_heights()
    Hf[600, 600] = -32768
    p = tmp_path / "N29E094.hgt"
    write_hgt(p, Hf)
    lat, lon, h, nvoid = read_hgt(p)
    assert nvoid == 1 and np.isnan(h[600, 600])
    t = GridTerrain.from_hgt([p])
    assert t.n_void == 1
    neighbours = {Hf[600 + di, 600 + dj] for di, dj in ((-1, 0), (1, 0), (0, -1), (0, 1))}
    assert t.height(29.5, 94.5) in neighbours
    t_nan = GridTerrain.from_hgt([p], fill_voids=False)
    assert np.isnan(t_nan.height(29.5, 94.5))


def test_hgt_mosaic_of_two_tiles(tmp_path):
    west, east = srtm3_heights(0), srtm3_heights(1)
    write_hgt(tmp_path / "N29E094.hgt", west)
    write_hgt(tmp_path / "n29e095.hgt", east)  # lower-case names are accepted
    t = GridTerrain.from_hgt([tmp_path / "N29E094.hgt", tmp_path / "n29e095.hgt"])
    assert t.extent_deg == pytest.approx((29.0, 30.0, 94.0, 96.0))
    assert t.height(29.5, 94.5) == pytest.approx(west[600, 600], abs=NODE_TOL_M)
    assert t.height(29.5, 95.5) == pytest.approx(east[600, 600], abs=NODE_TOL_M)
    assert t.height(29.5, 95.0) == pytest.approx(east[600, 0], abs=NODE_TOL_M)  # shared edge: later wins


def test_npz_round_trip_with_descending_latitude(tmp_path):
    rng = np.random.default_rng(2)
    lat = np.linspace(29.5, 29.1, 41)  # descending: the loader flips it
    lon = np.linspace(94.1, 94.6, 51)
    H = 3000 + 1000 * rng.random((41, 51))
    np.savez(tmp_path / "grid.npz", lat_deg=lat, lon_deg=lon, height_m=H)
    t = load_terrain(TerrainSettings(kind="dem", dem_paths=["grid.npz"]), tmp_path)
    i, j = rng.integers(0, 41, 100), rng.integers(0, 51, 100)
    np.testing.assert_allclose(t.height(lat[i], lon[j]), H[i, j], atol=NODE_TOL_M + 3e-4, rtol=0)
    qlat, qlon = rng.uniform(29.1, 29.5, 200), rng.uniform(94.1, 94.6, 200)
    ref = bilinear_reference(lat[::-1], lon, H[::-1], qlat, qlon)
    np.testing.assert_allclose(t.height(qlat, qlon), ref, atol=BILINEAR_TOL_M, rtol=0)


def test_grid_line_of_sight_over_a_generated_dem(tmp_path):
    """A DEM flat at 1000 m with one ridge row: rays across the ridge are blocked, above it clear."""
    lat = np.linspace(29.0, 29.2, 201)
    lon = np.linspace(94.0, 94.2, 201)
    H = np.full((201, 201), 1000.0)
    H[100, :] = 2000.0  # a 1000 m ridge along latitude 29.1
    t = GridTerrain(lat, lon, H)
    o = geodetic_to_ecef(29.05, 94.1, 1100.0)
    below = geodetic_to_ecef(29.15, 94.1, 1100.0)
    above = geodetic_to_ecef(29.15, 94.1, 3500.0)
    np.testing.assert_array_equal(t.line_of_sight(o, np.stack([below, above])), [False, True])


# --------------------------------------------------------------------------------------
# Bad inputs: clear errors naming the file
# --------------------------------------------------------------------------------------
def test_missing_dem_file_is_named(tmp_path):
    s = TerrainSettings(kind="dem", dem_paths=["nowhere/N29E094.hgt"])
    with pytest.raises(FileNotFoundError, match=r"dem_paths\[0\].*nowhere.N29E094\.hgt"):
        load_terrain(s, tmp_path)


def test_wrong_hgt_size_is_named(tmp_path):
    p = tmp_path / "N29E094.hgt"
    np.zeros((1000, 1000), ">i2").tofile(p)
    with pytest.raises(ValueError, match=r"N29E094\.hgt.*1201x1201.*got 2000000 bytes"):
        GridTerrain.from_hgt([p])


def test_bad_hgt_name_is_named(tmp_path):
    p = tmp_path / "tile.hgt"
    write_hgt(p, srtm3_heights())
    with pytest.raises(ValueError, match=r"tile\.hgt.*N29E094\.hgt"):
        GridTerrain.from_hgt([p])


def test_npz_missing_key_is_named(tmp_path):
    p = tmp_path / "grid.npz"
    np.savez(p, lat_deg=np.arange(3.0), lon_deg=np.arange(4.0))
    with pytest.raises(ValueError, match=r"grid\.npz.*missing \['height_m'\]"):
        GridTerrain.from_npz(p)


def test_npz_bad_shapes_and_irregular_axis_are_named(tmp_path):
    p = tmp_path / "grid.npz"
    np.savez(p, lat_deg=np.arange(3.0), lon_deg=np.arange(4.0), height_m=np.zeros((4, 3)))
    with pytest.raises(ValueError, match=r"grid\.npz.*height_m \(4, 3\)"):
        GridTerrain.from_npz(p)
    np.savez(p, lat_deg=np.array([0.0, 1.0, 3.0]), lon_deg=np.arange(4.0), height_m=np.zeros((3, 4)))
    with pytest.raises(ValueError, match=r"grid\.npz: lat_deg: expected a regular"):
        GridTerrain.from_npz(p)
    bad = tmp_path / "junk.npz"
    bad.write_bytes(b"not a zip file")
    with pytest.raises(ValueError, match=r"junk\.npz: not a readable \.npz"):
        GridTerrain.from_npz(bad)


@pytest.mark.parametrize("kw,match", [
    ({"kind": "dem"}, "needs dem_paths"),
    ({"kind": "dem", "dem_paths": ["a.tif"]}, "expected .hgt or .npz"),
    ({"kind": "dem", "dem_paths": ["a.npz", "b.npz"]}, "one .npz"),
    ({"kind": "mountains"}, "linzhi_synthetic"),
    ({"ridge_height": 5.0}, "Extra inputs"),
    ({"ridge_base_width_m": 7000.0}, "overlap"),
    ({"max_range_m": -1.0}, "greater than 0"),
])
def test_settings_reject_bad_values(kw, match):
    with pytest.raises(ValidationError, match=match):
        TerrainSettings(**kw)


def test_settings_build_each_kind():
    assert isinstance(load_terrain(TerrainSettings()), LinZhiSyntheticValley)
    assert load_terrain(TerrainSettings()) is load_terrain(TerrainSettings())  # one per process
    f = load_terrain(TerrainSettings(kind="flat", flat_height_m=100.0))
    assert isinstance(f, Flat) and f.height(10.0, 20.0) == 100.0
    r = load_terrain(TerrainSettings(kind="two_ridges", ridge_height_m=500.0, ridge_course_deg=54.65))
    assert isinstance(r, TwoRidges) and r.h_max == pytest.approx(2950.0 + 500.0)

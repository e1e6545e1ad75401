"""Readers for gridded elevation files: SRTM ``.hgt`` tiles and plain ``.npz`` grids.

They return plain arrays ``(lat_deg (M,), lon_deg (N,), height_m (M, N))`` with
latitude and longitude ascending; :class:`testbed.world.terrain.GridTerrain`
turns them into a terrain model.

Heights: SRTM heights are EGM96 orthometric (above the geoid). The testbed has
no geoid model and treats every height as WGS84 ellipsoidal (see
docs/design/physics-notes.md §heights); near ZUNZ the EGM96 undulation is a few tens of metres, so a real
tile sits that much off the ellipsoidal heights JSBSim flies in. A user who
cares converts the grid to ellipsoidal heights before saving it as ``.npz``.

GeoTIFF is not read: no light TIFF reader (tifffile, rasterio) is a dependency.
Convert a GeoTIFF to ``.npz`` (``lat_deg``, ``lon_deg``, ``height_m``) instead.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
from numpy.typing import NDArray
from scipy import ndimage

#: SRTM void marker.
HGT_VOID = -32768
#: Samples per side of an SRTM tile by resolution (1 arc-second, 3 arc-seconds).
HGT_SIZES = {3601: 1.0, 1201: 3.0}
_HGT_NAME = re.compile(r"^([NS])(\d{2})([EW])(\d{3})\.hgt$", re.IGNORECASE)
#: Relative tolerance on the spacing of a "regular" grid.
_REGULAR_RTOL = 1e-6


def hgt_corner(path: Path | str) -> tuple[int, int]:
    """South-west corner ``(lat_deg, lon_deg)`` from an SRTM file name like ``N29E094.hgt``."""
    p = Path(path)
    m = _HGT_NAME.match(p.name)
    if m is None:
        raise ValueError(f"{p}: an SRTM tile name must look like N29E094.hgt "
                         f"(hemisphere, 2-digit latitude, hemisphere, 3-digit longitude), got {p.name!r}")
    lat = int(m.group(2)) * (1 if m.group(1).upper() == "N" else -1)
    lon = int(m.group(4)) * (1 if m.group(3).upper() == "E" else -1)
    if not (-90 <= lat < 90 and -180 <= lon < 180):
        raise ValueError(f"{p}: tile corner ({lat}, {lon}) is not a valid latitude/longitude")
    return lat, lon


def read_hgt(path: Path | str) -> tuple[NDArray, NDArray, NDArray, int]:
    """Read one SRTM ``.hgt`` tile.

    Returns
    -------
    lat_deg : (n,) ascending; lon_deg : (n,) ascending; height_m : (n, n) float64
    with voids (-32768) as NaN; n_void : number of void samples.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"DEM file not found: {p}")
    lat0, lon0 = hgt_corner(p)
    size = p.stat().st_size
    n = next((k for k in HGT_SIZES if size == 2 * k * k), None)
    if n is None:
        raise ValueError(f"{p}: an SRTM .hgt tile has 3601x3601 (1\") or 1201x1201 (3\") "
                         f"big-endian int16 samples ({2 * 3601**2} or {2 * 1201**2} bytes), "
                         f"got {size} bytes")
    raw = np.fromfile(p, dtype=">i2").reshape(n, n)
    void = raw == HGT_VOID
    h = raw.astype(np.float64)
    h[void] = np.nan
    # File rows run north to south; we store latitude ascending.
    h = h[::-1]
    ax = np.linspace(0.0, 1.0, n)
    return lat0 + ax, lon0 + ax, h, int(void.sum())


def read_hgt_mosaic(paths: list[Path | str]) -> tuple[NDArray, NDArray, NDArray, int]:
    """Read several SRTM tiles of one resolution into one grid (missing tiles are NaN).

    Adjacent tiles share their edge row/column; the later file wins there.
    """
    if not paths:
        raise ValueError("read_hgt_mosaic: no .hgt files given")
    tiles = [read_hgt(p) for p in paths]
    sizes = {t[2].shape[0] for t in tiles}
    if len(sizes) != 1:
        raise ValueError(f"{[str(p) for p in paths]}: tiles mix resolutions (sizes {sorted(sizes)}); "
                         "use tiles of one resolution")
    n = sizes.pop()
    corners = [hgt_corner(p) for p in paths]
    lat_min = min(c[0] for c in corners)
    lon_min = min(c[1] for c in corners)
    n_lat = max(c[0] for c in corners) - lat_min + 1
    n_lon = max(c[1] for c in corners) - lon_min + 1
    M, N = n_lat * (n - 1) + 1, n_lon * (n - 1) + 1
    h = np.full((M, N), np.nan)
    for (lat0, lon0), (_, _, ht, _) in zip(corners, tiles):
        i, j = (lat0 - lat_min) * (n - 1), (lon0 - lon_min) * (n - 1)
        h[i:i + n, j:j + n] = ht
    lat = lat_min + np.arange(M) / (n - 1)
    lon = lon_min + np.arange(N) / (n - 1)
    return lat, lon, h, sum(t[3] for t in tiles)


def read_npz(path: Path | str) -> tuple[NDArray, NDArray, NDArray]:
    """Read a plain grid: arrays ``lat_deg (M,)``, ``lon_deg (N,)``, ``height_m (M, N)``.

    Axes may be ascending or descending (they are returned ascending) but must
    be regularly spaced.
    """
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"DEM file not found: {p}")
    try:
        z = np.load(p, allow_pickle=False)
    except Exception as e:
        raise ValueError(f"{p}: not a readable .npz file ({type(e).__name__}: {e})") from e
    if not isinstance(z, np.lib.npyio.NpzFile):
        raise ValueError(f"{p}: expected an .npz archive of named arrays, got a single array")
    with z:
        missing = [k for k in ("lat_deg", "lon_deg", "height_m") if k not in z.files]
        if missing:
            raise ValueError(f"{p}: a terrain .npz needs arrays lat_deg (M,), lon_deg (N,), "
                             f"height_m (M, N); missing {missing} (found {sorted(z.files)})")
        lat = np.asarray(z["lat_deg"], float)
        lon = np.asarray(z["lon_deg"], float)
        h = np.asarray(z["height_m"], float)
    if lat.ndim != 1 or lon.ndim != 1 or h.shape != (lat.size, lon.size):
        raise ValueError(f"{p}: expected lat_deg (M,), lon_deg (N,), height_m (M, N); got "
                         f"lat_deg {lat.shape}, lon_deg {lon.shape}, height_m {h.shape}")
    if lat.size < 2 or lon.size < 2:
        raise ValueError(f"{p}: the grid needs at least 2 rows and 2 columns, got {h.shape}")
    if lat[1] < lat[0]:
        lat, h = lat[::-1], h[::-1]
    if lon[1] < lon[0]:
        lon, h = lon[::-1], h[:, ::-1]
    for name, ax in (("lat_deg", lat), ("lon_deg", lon)):
        check_regular(ax, f"{p}: {name}")
    return lat, lon, h


def check_regular(ax: NDArray, where: str) -> None:
    """Raise ValueError unless ``ax`` is finite, strictly increasing and evenly spaced."""
    d = np.diff(ax)
    if not np.all(np.isfinite(ax)) or np.any(d <= 0):
        raise ValueError(f"{where}: expected finite, strictly monotonic values")
    if np.max(np.abs(d - d.mean())) > _REGULAR_RTOL * abs(d.mean()) + 1e-12:
        raise ValueError(f"{where}: expected a regular (evenly spaced) axis, spacing varies "
                         f"from {d.min():.9g} to {d.max():.9g} deg")


def fill_voids_nearest(h: NDArray) -> NDArray:
    """A copy of ``h`` with NaN samples replaced by the nearest valid sample."""
    void = ~np.isfinite(h)
    if not void.any() or void.all():
        return h.copy()
    idx = ndimage.distance_transform_edt(void, return_distances=False, return_indices=True)
    return h[tuple(idx)]

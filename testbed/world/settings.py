"""Settings of the world room: which terrain model the run uses.

``[terrain]`` in an approach file; :func:`load_terrain` builds the model.
Paths are relative to the file that names them (the caller passes its folder).
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import Literal

from pydantic import Field, model_validator

from testbed.schema import StrictModel
from testbed.world import airport
from testbed.world.terrain import Flat, GridTerrain, Terrain, TwoRidges
from testbed.world.valley import LinZhiSyntheticValley


class TerrainSettings(StrictModel):
    """The terrain model: the synthetic LinZhi valley (default), the paper's two ridges,
    a flat plane, or a user's DEM (SRTM ``.hgt`` tiles or one ``.npz`` grid)."""

    kind: Literal["linzhi_synthetic", "two_ridges", "flat", "dem"] = Field(
        "linzhi_synthetic", description="terrain model; 'linzhi_synthetic' is SYNTHETIC (not a survey)")
    max_range_m: float = Field(150e3, gt=0, le=500e3,
                               description="how far sky visibility and horizon masks look, m")
    # flat
    flat_height_m: float = Field(airport.ELEVATION_M, ge=-500, le=9000,
                                 description="kind='flat': height of the plane, m ellipsoidal")
    # two_ridges (the VA-RAIM paper §3.1; docs/design/physics-notes.md §va-raim-scenario-terrain)
    ridge_centre_lat_deg: float = Field(airport.VA_RAIM_CENTRE[0], ge=-89, le=89,
                                        description="kind='two_ridges': centre between the ridges")
    ridge_centre_lon_deg: float = Field(airport.VA_RAIM_CENTRE[1], ge=-180, le=180,
                                        description="kind='two_ridges': longitude of the centre")
    ridge_field_height_m: float = Field(airport.VA_RAIM_CENTRE[2], ge=-500, le=9000,
                                        description="floor height between the ridges, m ellipsoidal")
    ridge_offset_m: float = Field(3000.0, gt=0, le=50e3,
                                  description="crest distance either side of the centre, m")
    ridge_height_m: float = Field(1000.0, ge=0, le=9000, description="crest height above the floor, m")
    ridge_course_deg: float = Field(90.0, ge=0, le=360,
                                    description="direction of the ridges (the approach course), deg true")
    ridge_base_width_m: float = Field(2000.0, gt=0,
                                      description="base width of each raised-cosine ridge, m")
    # dem
    dem_paths: list[Path] = Field(default_factory=list,
                                  description="kind='dem': SRTM .hgt tiles (one resolution) or one .npz")
    dem_fill_voids: bool = Field(True, description="fill DEM voids from the nearest valid sample")

    @model_validator(mode="after")
    def _check(self) -> "TerrainSettings":
        if self.ridge_base_width_m > 2 * self.ridge_offset_m:
            raise ValueError(f"ridge_base_width_m ({self.ridge_base_width_m}) must not exceed "
                             f"2 * ridge_offset_m ({2 * self.ridge_offset_m}): the ridges would overlap")
        if self.kind == "dem":
            if not self.dem_paths:
                raise ValueError("kind='dem' needs dem_paths (SRTM .hgt tiles or one .npz file)")
            suffixes = {p.suffix.lower() for p in self.dem_paths}
            if not suffixes <= {".hgt", ".npz"}:
                raise ValueError(f"dem_paths: expected .hgt or .npz files, got suffixes {sorted(suffixes)}")
            if ".npz" in suffixes and len(self.dem_paths) != 1:
                raise ValueError("dem_paths: give one .npz file, or only .hgt tiles")
        return self


@functools.lru_cache(maxsize=4)
def _linzhi(max_range_m: float) -> LinZhiSyntheticValley:
    # Immutable and ~20 MB: one per process.
    return LinZhiSyntheticValley(max_range_m=max_range_m)


def load_terrain(settings: TerrainSettings, base_dir: Path | str = ".") -> Terrain:
    """Build the terrain model described by ``settings``.

    ``dem_paths`` are resolved relative to ``base_dir`` (the folder of the file that
    names them). A missing DEM file raises FileNotFoundError naming the setting and
    the resolved path; a malformed one raises ValueError naming the file.
    """
    s = settings
    if s.kind == "linzhi_synthetic":
        return _linzhi(float(s.max_range_m))
    if s.kind == "flat":
        return Flat(s.flat_height_m, max_range_m=s.max_range_m)
    if s.kind == "two_ridges":
        return TwoRidges(s.ridge_centre_lat_deg, s.ridge_centre_lon_deg, s.ridge_field_height_m,
                         offset_m=s.ridge_offset_m, height_m=s.ridge_height_m,
                         course_deg=s.ridge_course_deg, base_width_m=s.ridge_base_width_m,
                         max_range_m=s.max_range_m)
    base = Path(base_dir)
    paths = []
    for i, p in enumerate(s.dem_paths):
        full = p if p.is_absolute() else base / p
        if not full.is_file():
            raise FileNotFoundError(f"terrain.dem_paths[{i}]: DEM file not found: {full} "
                                    f"(relative paths are relative to {base})")
        paths.append(full)
    if paths[0].suffix.lower() == ".npz":
        return GridTerrain.from_npz(paths[0], fill_voids=s.dem_fill_voids, max_range_m=s.max_range_m)
    return GridTerrain.from_hgt(paths, fill_voids=s.dem_fill_voids, max_range_m=s.max_range_m)

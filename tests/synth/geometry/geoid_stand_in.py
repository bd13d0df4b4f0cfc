"""A stand-in for Lantmäteriet's SWEN17_RH2000 geoid grid, for tests: a GeoTIFF PROJ reads like
the real one, with a constant geoid height, so a machine "has the grid" when PROJ looks in its
folder. Not the real geoid: heights computed with it are ellipsoidal minus ``offset_m``."""

from __future__ import annotations

from pathlib import Path

GRID_NAME = "se_lantmateriet_SWEN17_RH2000.tif"  # the name synth.geometry.geodesy.RH2000_GRID asks PROJ for


def write_stand_in_geoid(folder: str | Path, offset_m: float = 30.0) -> Path:
    """Write the stand-in grid (0.5 deg cells over 10-25 deg E, 55-70 deg N) into ``folder``."""
    import numpy as np
    from PIL import Image, TiffImagePlugin, TiffTags

    path = Path(folder) / GRID_NAME
    path.parent.mkdir(parents=True, exist_ok=True)
    tags = TiffImagePlugin.ImageFileDirectory_v2()
    for tag, kind, value in (
        (277, TiffTags.SHORT, 1),  # SamplesPerPixel
        (284, TiffTags.SHORT, 1),  # PlanarConfiguration: contiguous
        (33550, TiffTags.DOUBLE, (0.5, 0.5, 0.0)),  # ModelPixelScale [deg]
        (33922, TiffTags.DOUBLE, (0.0, 0.0, 0.0, 10.0, 70.0, 0.0)),  # ModelTiepoint: pixel (0, 0) at 10 E, 70 N
        # GeoKeyDirectory: geographic model, pixel is point, SWEREF 99 (EPSG:4619)
        (34735, TiffTags.SHORT, (1, 1, 0, 3, 1024, 0, 1, 2, 1025, 0, 1, 2, 2048, 0, 1, 4619)),
    ):
        tags[tag] = value
        tags.tagtype[tag] = kind
    Image.fromarray(np.full((31, 31), offset_m, np.float32), mode="F").save(path, tiffinfo=tags)
    return path

"""Map files as twin data: OpenDRIVE (.xodr) and OpenStreetMap (.osm, .osm.pbf) read into the
`TwinSpec` fields (`twin.schema`) that `twin.model.load_twin` validates."""

from __future__ import annotations

from pathlib import Path

from blendgen.errors import UserError

FORMATS = {".xodr": "opendrive", ".osm": "osm", ".pbf": "osm"}


def map_format(path: Path) -> str | None:
    return FORMATS.get(Path(path).suffix.lower())


def map_twin_data(path, fmt: str | None = None) -> dict:
    """TwinSpec data for a map file (OpenDRIVE or OpenStreetMap)."""
    path = Path(path)
    fmt = fmt or map_format(path)
    if fmt == "opendrive":
        from blendgen.twin.opendrive import read_opendrive, twin_data

        return twin_data(read_opendrive(path))
    if fmt == "osm":
        from blendgen.twin.osm import twin_data_from_osm

        return twin_data_from_osm(path)
    raise UserError(f"unknown map format {path.suffix!r}; expected .xodr, .osm or .osm.pbf", where=str(path))

"""GoPro GPMF telemetry (KLV) parser, after GoPro's published format description.

Each record: 4-byte FourCC key, 1-byte type, 1-byte struct size, 2-byte repeat count
(big endian), then size*repeat bytes of payload padded to a multiple of 4. Type 0 nests.
Within a DEVC (device), each STRM (stream) holds "sticky" descriptors (SCAL, SIUN,
STNM, TSMP, STMP, ORIN, TYPE, ...) followed by its data key (ACCL, GYRO, GPS5, CORI...).
Scaled values are raw / SCAL (one scale for all columns or one per column).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field

import numpy as np

# type char -> numpy big-endian dtype
_DTYPES = {
    "b": ">i1", "B": ">u1", "c": "S1", "d": ">f8", "f": ">f4", "F": "S4", "G": "S16",
    "j": ">i8", "J": ">u8", "l": ">i4", "L": ">u4", "q": ">u4", "Q": ">u8",
    "s": ">i2", "S": ">u2", "U": "S16",
}


class GpmfError(ValueError):
    pass


@dataclass
class Klv:
    key: str
    type: str  # '\0' for nested
    size: int
    repeat: int
    payload: bytes
    children: list["Klv"] = field(default_factory=list)

    def value(self, type_override: str | None = None) -> np.ndarray | str | list:
        """Decoded payload: numbers as an (repeat, columns) array, strings as str."""
        t = type_override or self.type
        if t in ("c", "U"):
            if self.size <= 1 or self.repeat == 1:
                return self.payload[: self.size * self.repeat].split(b"\0")[0].decode("latin-1", "replace")
            return ",".join(self.payload[i:i + self.size].split(b"\0")[0].decode("latin-1", "replace")
                            for i in range(0, self.size * self.repeat, self.size))
        if t == "F":
            return [self.payload[i:i + 4].decode("latin-1") for i in range(0, self.size * self.repeat, 4)]
        if len(t) > 1:  # complex structure described by TYPE, e.g. 'Lffff'
            return _decode_complex(self.payload[: self.size * self.repeat], t, self.repeat)
        if t not in _DTYPES:
            raise GpmfError(f"{self.key}: unknown GPMF type {t!r}")
        dt = np.dtype(_DTYPES[t])
        n = self.size * self.repeat // dt.itemsize
        arr = np.frombuffer(self.payload, dtype=dt, count=n).astype(float)
        if t == "q":
            arr = arr / 65536.0
        elif t == "Q":
            arr = arr / 4294967296.0
        cols = max(1, self.size // dt.itemsize)
        return arr.reshape(self.repeat, cols)


def _decode_complex(payload: bytes, typedef: str, repeat: int) -> np.ndarray:
    fields = [np.dtype(_DTYPES[c]) for c in typedef]
    rec = np.dtype([(f"f{i}", d) for i, d in enumerate(fields)])
    arr = np.frombuffer(payload, dtype=rec, count=repeat)
    return np.stack([arr[f"f{i}"].astype(float) for i in range(len(fields))], axis=1)


def parse(buf: bytes, offset: int = 0, end: int | None = None) -> list[Klv]:
    """Parse a GPMF buffer into a KLV tree. Raises GpmfError on truncated or corrupt data."""
    end = len(buf) if end is None else end
    out = []
    pos = offset
    while pos + 8 <= end:
        key_b, t, size, repeat = struct.unpack(">4scBH", buf[pos:pos + 8])
        if key_b == b"\0\0\0\0":  # padding at the end of a payload
            break
        try:
            key = key_b.decode("ascii")
        except UnicodeDecodeError:
            raise GpmfError(f"invalid key {key_b!r} at byte {pos}") from None
        if not key.isprintable():
            raise GpmfError(f"invalid key {key_b!r} at byte {pos}")
        n = size * repeat
        padded = (n + 3) & ~3
        if pos + 8 + padded > end:
            raise GpmfError(f"{key} at byte {pos} needs {padded} bytes but only {end - pos - 8} remain (truncated)")
        payload = buf[pos + 8:pos + 8 + n]
        tc = t.decode("latin-1")
        node = Klv(key, tc, size, repeat, payload)
        if t == b"\0":
            node.children = parse(buf, pos + 8, pos + 8 + n)
        out.append(node)
        pos += 8 + padded
    return out


@dataclass
class StreamSamples:
    """One stream's samples in one payload, scaled to physical units."""

    key: str
    values: np.ndarray  # (n, columns), scaled
    units: str
    name: str
    orin: str | None  # axis order, e.g. 'ZXY' (HERO6+)
    stmp_us: float | None  # microsecond timestamp of the first sample, when the camera wrote one
    tsmp: int | None  # total samples so far (sticky running count)


def streams(payload_tree: list[Klv], keys: set[str]) -> list[StreamSamples]:
    """Data streams with the given keys found in one payload, scaled."""
    out = []
    for devc in payload_tree:
        if devc.key != "DEVC":
            continue
        for strm in devc.children:
            if strm.key != "STRM":
                continue
            sticky: dict[str, Klv] = {}
            for j, k in enumerate(strm.children):
                if k.key in keys:
                    # SCAL belongs to the stream's data (its last key); descriptors such as GPSP, GPSF
                    # or GPSU that sit in the same stream are returned unscaled
                    out.append(_scaled(k, sticky, scale=j == len(strm.children) - 1))
                else:
                    sticky[k.key] = k
    return out


def _scaled(k: Klv, sticky: dict[str, Klv], scale: bool = True) -> StreamSamples:
    type_override = sticky["TYPE"].value("c") if k.type == "?" and "TYPE" in sticky else None
    vals = np.asarray(k.value(type_override), dtype=float)
    if scale and "SCAL" in sticky:
        scal = np.asarray(sticky["SCAL"].value(), dtype=float).ravel()
        if np.any(scal == 0):
            raise GpmfError(f"{k.key}: SCAL contains 0")
        if scal.size == 1 or scal.size == vals.shape[1]:
            vals = vals / scal.reshape(1, -1)
        else:
            raise GpmfError(f"{k.key}: SCAL has {scal.size} values for {vals.shape[1]} columns")
    units = ""
    for u in ("SIUN", "UNIT"):
        if u in sticky:
            units = sticky[u].value("c")
            break
    name = sticky["STNM"].value("c") if "STNM" in sticky else ""
    orin = sticky["ORIN"].value("c") if "ORIN" in sticky else None
    stmp = float(sticky["STMP"].value().ravel()[0]) if "STMP" in sticky else None
    tsmp = int(sticky["TSMP"].value().ravel()[0]) if "TSMP" in sticky else None
    return StreamSamples(k.key, vals, units, name, orin, stmp, tsmp)

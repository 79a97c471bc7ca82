"""A small ISO-BMFF (MP4/MOV) reader: track sample tables, without decoding anything.

Used for exact per-frame presentation times of video tracks and to pull the raw samples of
the GoPro `gpmd` metadata track (no ffmpeg needed). Boxes per ISO/IEC 14496-12.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from blendgen.errors import UserError

_CONTAINERS = {b"moov", b"trak", b"mdia", b"minf", b"stbl", b"edts", b"udta", b"dinf"}


@dataclass
class Track:
    handler: str  # 'vide', 'soun', 'meta', ...
    codec: str  # sample entry type: 'avc1', 'hvc1', 'gpmd', ...
    timescale: int
    sample_sizes: np.ndarray  # (N,) bytes
    sample_offsets: np.ndarray  # (N,) absolute file offsets
    decode_times: np.ndarray  # (N,) in timescale units
    durations: np.ndarray  # (N,) in timescale units
    composition_offsets: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))
    edit_media_time: int = 0  # first edit's media_time (timescale units), 0 without an edit list

    @property
    def n_samples(self) -> int:
        return len(self.sample_sizes)

    def presentation_times(self) -> np.ndarray:
        """Presentation time of each sample in seconds (decode order), edit list applied."""
        t = self.decode_times.astype(np.int64)
        if len(self.composition_offsets):
            t = t + self.composition_offsets
        return (t - self.edit_media_time) / float(self.timescale)


def _boxes(f, start: int, end: int, path: Path):
    pos = start
    while pos + 8 <= end:
        f.seek(pos)
        head = f.read(8)
        if len(head) < 8:
            raise UserError(f"truncated MP4 box header at byte {pos}", where=str(path))
        size, kind = struct.unpack(">I4s", head)
        hdr = 8
        if size == 1:
            size = struct.unpack(">Q", f.read(8))[0]
            hdr = 16
        elif size == 0:
            size = end - pos
        if size < hdr or pos + size > end:
            raise UserError(f"MP4 box {kind!r} at byte {pos} claims {size} bytes but only {end - pos} remain "
                            "(truncated or corrupt file)", where=str(path))
        yield kind, pos + hdr, pos + size
        pos += size


def read_tracks(path: str | Path) -> list[Track]:
    """All tracks of an MP4/MOV file with their sample tables."""
    path = Path(path)
    try:
        f = open(path, "rb")
    except OSError as e:
        raise UserError(f"cannot open: {e.strerror}", where=str(path)) from None
    with f:
        size = path.stat().st_size
        top = {k: (s, e) for k, s, e in _boxes(f, 0, size, path)}
        if b"moov" not in top:
            raise UserError("no 'moov' box: not an MP4/MOV file, or the recording was cut off before the "
                            "camera finished writing it", where=str(path))
        tracks = []
        for kind, s, e in _boxes(f, *top[b"moov"], path):
            if kind == b"trak":
                tracks.append(_read_trak(f, s, e, path))
        for tr in tracks:
            if tr.n_samples and int(tr.sample_offsets[-1] + tr.sample_sizes[-1]) > size:
                raise UserError(f"{tr.handler} track ({tr.codec}) points past the end of the file "
                                f"({int(tr.sample_offsets[-1] + tr.sample_sizes[-1])} > {size} bytes): truncated",
                                where=str(path))
        return tracks


def read_user_data(path: str | Path) -> dict[str, bytes]:
    """The boxes inside moov/udta (a camera's own metadata: GoPro writes FIRM, LENS, CAME, SETT)."""
    path = Path(path)
    with open(path, "rb") as f:
        top = {k: (s, e) for k, s, e in _boxes(f, 0, path.stat().st_size, path)}
        if b"moov" not in top:
            return {}
        out = {}
        for kind, s, e in _boxes(f, *top[b"moov"], path):
            if kind == b"udta":
                for k, cs, ce in _boxes(f, s, e, path):
                    f.seek(cs)
                    out[k.decode("latin-1")] = f.read(ce - cs)
        return out


def _collect(f, s, e, path, out: dict):
    for kind, cs, ce in _boxes(f, s, e, path):
        if kind in _CONTAINERS:
            _collect(f, cs, ce, path, out)
        else:
            f.seek(cs)
            out[kind] = f.read(ce - cs)


def _read_trak(f, s, e, path) -> Track:
    b: dict = {}
    _collect(f, s, e, path, b)
    try:
        handler = b[b"hdlr"][8:12].decode("latin-1")
        mdhd = b[b"mdhd"]
        timescale = struct.unpack(">I", mdhd[20:24] if mdhd[0] == 1 else mdhd[12:16])[0]
        stsd = b[b"stsd"]
        codec = stsd[12:16].decode("latin-1") if len(stsd) >= 16 else "?"
        sizes = _stsz(b[b"stsz"])
        chunk_offsets = _chunk_offsets(b)
        stsc = _table(b[b"stsc"], 3)
        deltas = _table(b[b"stts"], 2)
    except (KeyError, struct.error, IndexError) as e:
        raise UserError(f"a track lacks or has a broken sample table ({e}); the file is corrupt",
                        where=str(path)) from None
    n = len(sizes)
    durations = np.repeat(deltas[:, 1], deltas[:, 0]).astype(np.int64) if len(deltas) else np.zeros(0, np.int64)
    if len(durations) != n:
        raise UserError(f"{handler} track: time table has {len(durations)} samples, size table {n}; corrupt",
                        where=str(path))
    decode = np.concatenate([[0], np.cumsum(durations)[:-1]]).astype(np.int64) if n else durations
    offsets = _sample_offsets(sizes, chunk_offsets, stsc, path)
    ctts = np.zeros(0, dtype=np.int64)
    if b"ctts" in b:
        tab = _table(b[b"ctts"], 2, signed=True)
        ctts = np.repeat(tab[:, 1], tab[:, 0]).astype(np.int64)
        if len(ctts) != n:
            ctts = np.zeros(0, dtype=np.int64)
    media_time = 0
    if b"elst" in b:
        el = b[b"elst"]
        version, count = el[0], struct.unpack(">I", el[4:8])[0]
        for k in range(count):
            if version == 1:
                _, mt = struct.unpack(">Qq", el[8 + 20 * k: 24 + 20 * k])
            else:
                _, mt = struct.unpack(">Ii", el[8 + 12 * k: 16 + 12 * k])
            if mt >= 0:  # -1 marks an empty edit (a delay); the first real edit gives the start
                media_time = mt
                break
    return Track(handler, codec, timescale, sizes, offsets, decode, durations, ctts, media_time)


def _table(data: bytes, cols: int, signed: bool = False) -> np.ndarray:
    count = struct.unpack(">I", data[4:8])[0]
    raw = np.frombuffer(data[8:8 + 4 * cols * count], dtype=">i4" if signed else ">u4")
    if raw.size != cols * count:
        raise struct.error("table shorter than its entry count")
    return raw.reshape(count, cols).astype(np.int64)


def _stsz(data: bytes) -> np.ndarray:
    uniform, count = struct.unpack(">II", data[4:12])
    if uniform:
        return np.full(count, uniform, dtype=np.int64)
    raw = np.frombuffer(data[12:12 + 4 * count], dtype=">u4")
    if raw.size != count:
        raise struct.error("stsz shorter than its entry count")
    return raw.astype(np.int64)


def _chunk_offsets(b: dict) -> np.ndarray:
    if b"co64" in b:
        d = b[b"co64"]
        count = struct.unpack(">I", d[4:8])[0]
        return np.frombuffer(d[8:8 + 8 * count], dtype=">u8").astype(np.int64)
    d = b[b"stco"]
    count = struct.unpack(">I", d[4:8])[0]
    return np.frombuffer(d[8:8 + 4 * count], dtype=">u4").astype(np.int64)


def _sample_offsets(sizes, chunk_offsets, stsc, path) -> np.ndarray:
    offsets = np.zeros(len(sizes), dtype=np.int64)
    i = 0
    n_chunks = len(chunk_offsets)
    for k, (first, per_chunk, _desc) in enumerate(stsc):
        last = stsc[k + 1][0] - 1 if k + 1 < len(stsc) else n_chunks
        for c in range(first - 1, last):
            pos = chunk_offsets[c]
            for _ in range(per_chunk):
                if i >= len(sizes):
                    return offsets
                offsets[i] = pos
                pos += sizes[i]
                i += 1
    if i != len(sizes):
        raise UserError(f"sample-to-chunk table covers {i} of {len(sizes)} samples; corrupt", where=str(path))
    return offsets


def read_samples(path: str | Path, track: Track) -> list[bytes]:
    with open(path, "rb") as f:
        out = []
        for off, size in zip(track.sample_offsets, track.sample_sizes):
            f.seek(int(off))
            data = f.read(int(size))
            if len(data) != size:
                raise UserError(f"sample at byte {off} is cut off (file truncated)", where=str(path))
            out.append(data)
        return out

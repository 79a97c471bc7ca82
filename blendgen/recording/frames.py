"""A recording's frames by frame id (bpy-free): whether they are a sequence, their indices,
and the decoded frames in recording order."""

from __future__ import annotations

from blendgen.errors import UserError
from blendgen.recording.folder import iter_frames, read_frame


def is_sequence(rec) -> bool:
    """Frames in temporal order (a video, or image frames that are not a set of stills)."""
    return rec.video is not None or (rec.extra.get("import") or {}).get("format") != "images"


def frame_indices(rec, frame_ids) -> list[int]:
    index = {rec.frame_id(i): i for i in range(rec.n_frames)}
    bad = [f for f in frame_ids if f not in index]
    if bad:
        raise UserError(f"frame id(s) {bad[:3]} are not in the recording ({rec.n_frames} frames, "
                        f"f000000..{rec.frame_id(max(rec.n_frames - 1, 0))})", where=str(rec.root))
    return [index[f] for f in frame_ids]


def read_frames(rec, frame_ids, *, progress: bool = False, desc: str = "frames"):
    """Yield (frame_id, BGR) for the given ids in recording order (videos decode sequentially)."""
    idx = sorted(set(frame_indices(rec, frame_ids)))
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=len(idx), desc=desc, unit="frame")
    if rec.video is not None and len(idx) > 1:
        want = set(idx)
        gen = ((i, im) for i, im in iter_frames(rec, skip_bad=True) if i in want)
    else:
        gen = ((i, read_frame(rec, i)) for i in idx)
    for i, im in gen:
        if bar is not None:
            bar.update(1)
        yield rec.frame_id(i), im
        if i >= idx[-1]:
            break
    if bar is not None:
        bar.close()

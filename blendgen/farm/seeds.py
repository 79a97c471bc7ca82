"""Per-frame seeds derived from the job seed and the frame id, so that a frame's random
choices do not depend on which worker ran it, in which order, or after how many retries."""

from __future__ import annotations

import hashlib

SEED_BITS = 31  # fits Blender's signed 32-bit seed fields and numpy's SeedSequence


def frame_seed(job_seed: int, frame_id: str | int) -> int:
    """Deterministic seed in [0, 2**31) from (job seed, frame id) via BLAKE2b.

    A hash (not `job_seed + index`) keeps neighbouring frames' streams unrelated and stays
    stable when frames are added, removed or re-chunked.
    """
    digest = hashlib.blake2b(f"{int(job_seed)}/{frame_id}".encode("utf-8"), digest_size=8,
                             person=b"blendgen-frame").digest()
    return int.from_bytes(digest, "little") & ((1 << SEED_BITS) - 1)

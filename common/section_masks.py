"""The sections-on bitmask of the outputs: which sections' gates are open in a tick, as text.

A mask is hexadecimal, ``"0x..."``, bit k the k-th section counted from the left (``"0x3f"``: six
sections all on; ``"0x0"``: none). It is part of a message's encoding (the Zenoh rate stream's
``section_mask``, the track files' column), so it lives here, below every room: the simulation's outputs
write it, the bus and the web page read it back.
"""

from __future__ import annotations

import numpy as np

__all__ = ["section_masks", "section_mask_codes", "sections_from_masks"]


def section_masks(actual) -> list[str]:
    """Each tick's open gates as a hexadecimal bitmask: bool (n, sections) -> n strings ``"0x..."``."""
    codes, masks = section_mask_codes(actual)
    return np.array(masks, dtype=object)[codes].tolist()


def section_mask_codes(actual) -> tuple[np.ndarray, list[str]]:
    """`section_masks` as codes into the distinct masks: bool (n, sections) -> ``(codes, masks)``.

    Tick i's mask is ``masks[codes[i]]`` (a run has a few dozen distinct masks at most: each is written
    out once).
    """
    actual = np.asarray(actual, bool)
    if actual.shape[1] <= 63:
        bits = actual.astype(np.int64) @ (np.int64(1) << np.arange(actual.shape[1], dtype=np.int64))
        distinct, codes = np.unique(bits, return_inverse=True)
        return codes.reshape(-1), [f"0x{b:x}" for b in distinct.tolist()]
    packed = np.packbits(actual[:, ::-1], axis=1)  # the leftmost section in the lowest bit
    shift = packed.shape[1] * 8 - actual.shape[1]
    distinct, codes = np.unique(packed, axis=0, return_inverse=True)
    return codes.reshape(-1), [f"0x{int.from_bytes(row.tobytes(), 'big') >> shift:x}" for row in distinct]


def sections_from_masks(masks, sections: int) -> np.ndarray:
    """The gates of `section_masks` back: n strings -> bool (n, sections); ValueError names a bad mask."""
    values = [_mask_bits(mask, sections) for mask in masks]
    if sections <= 63:
        bits = np.array(values, dtype=np.int64).reshape(-1, 1)
        return ((bits >> np.arange(sections, dtype=np.int64)) & 1).astype(bool)
    return np.array([[(v >> k) & 1 for k in range(sections)] for v in values], bool).reshape(-1, sections)


def _mask_bits(mask, sections: int) -> int:
    try:
        bits = int(mask, 16) if isinstance(mask, str) and mask.startswith("0x") else -1
    except ValueError:
        bits = -1
    if not 0 <= bits < 1 << sections:
        raise ValueError(f"section mask {mask!r} is not a bitmask of {sections} sections (\"0x...\")")
    return bits

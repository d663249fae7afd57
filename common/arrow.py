"""numpy columns as Arrow arrays, made from their buffers.

``pyarrow.array`` of anything imports pandas first, to ask whether it was given one of pandas' objects:
some 40 MB in a process that needs nothing else of pandas (`vrsim run`'s, which writes its track and
as-applied points through Arrow while it holds the run's rasters). An Arrow array of a fixed-width type
is a validity bitmap and the values' bytes, a string array the texts' bytes and where each starts:
handed over as they are, with no pandas asked.
"""

from __future__ import annotations

import numpy as np


def arrow_array(values, nan_is_null: bool = False):
    """A one-dimensional numeric, datetime64 or text column as a ``pyarrow.Array`` of the same values.

    Parameters
    ----------
    values : array_like
        Integers or floats (the same Arrow type), datetime64 (a timestamp of the same unit) or texts
        (str or an object array of str: UTF-8 strings).
    nan_is_null : bool
        Floats' NaN as null (what ``pyarrow.array(..., from_pandas=True)`` does), else kept as NaN.
    """
    import pyarrow as pa

    values = np.asarray(values)
    if values.dtype.kind in "OU":
        return _strings(pa, [str(v) for v in values.tolist()])
    values = np.ascontiguousarray(values)
    nulls = np.isnan(values) if nan_is_null and values.dtype.kind == "f" else None
    count = int(nulls.sum()) if nulls is not None else 0
    # Arrow's validity bitmap: bit k of byte k // 8 for value k, least significant first.
    validity = pa.py_buffer(np.packbits(~nulls, bitorder="little")) if count else None
    return pa.Array.from_buffers(pa.from_numpy_dtype(values.dtype), len(values),
                                 [validity, pa.py_buffer(values.view(np.uint8))], null_count=count)


def _strings(pa, texts: list[str]):
    encoded = [text.encode() for text in texts]
    offsets = np.zeros(len(encoded) + 1, np.int32)
    np.cumsum([len(e) for e in encoded], out=offsets[1:])
    return pa.Array.from_buffers(pa.string(), len(encoded),
                                 [None, pa.py_buffer(offsets), pa.py_buffer(b"".join(encoded))])

"""The warning category for maps that are usable but not quite right (the CLI prints them as one line)."""


class MapWarning(UserWarning):
    """A map read with a repair: undefined zones as nodata, a wrong declared file length, ..."""

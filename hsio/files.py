"""Reading an input file whole, bounded: what hsio reads (configurations, structure files,
ground motions) is a regular file of a sensible size, never a device that would be read for
ever (/dev/zero) nor a file that would fill the memory."""

from __future__ import annotations

from pathlib import Path


def read_bounded(path: str | Path, limit: int, refused) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them. A path that is not a
    regular file, or a larger file, raises ``refused(reason)`` (an exception built by the caller,
    naming the file as it wants); an OSError of the read passes through."""
    path = Path(path)
    if path.exists() and not path.is_file():
        raise refused("not a regular file")
    with path.open("rb") as f:
        data = f.read(limit + 1)
    if len(data) > limit:
        raise refused(f"more than {limit} bytes")
    return data

"""Reading an input file whole, bounded: what hsio reads (configurations, structure files,
ground motions) is a regular file of a sensible size, never a device that would be read for
ever (/dev/zero) nor a file that would fill the memory."""

from __future__ import annotations

import os
from pathlib import Path

CHUNK_BYTES = 1 << 20


def read_bounded(path: str | Path, limit: int, refused) -> bytes:
    """The bytes of the regular file ``path``, at most ``limit`` of them. A path that is not a
    regular file, or a larger file, raises ``refused(reason)`` (an exception built by the caller,
    naming the file as it wants); an OSError of the read passes through.

    The file is read in chunks: the memory it takes is that of its bytes, never ``limit``
    reserved in advance, and a file that grows while it is read stops at the bound."""
    path = Path(path)
    if path.exists() and not path.is_file():
        raise refused("not a regular file")
    with path.open("rb") as f:
        if os.fstat(f.fileno()).st_size > limit:
            raise refused(f"more than {limit} bytes")
        data = bytearray()
        while len(data) <= limit:
            chunk = f.read(min(CHUNK_BYTES, limit + 1 - len(data)))
            if not chunk:
                break
            data += chunk
    if len(data) > limit:
        raise refused(f"more than {limit} bytes")
    return bytes(data)

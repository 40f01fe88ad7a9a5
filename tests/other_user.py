"""Running a check as a user other than the file's owner (tests of write-protected records and
ledgers): as root, permissions do not apply, so the check runs as nobody through setpriv."""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import pytest


def as_other_user(what: str) -> list[str]:
    """The command prefix that runs a process as another user ([] when not root), or skip naming
    ``what`` it was for where setpriv is absent."""
    if os.geteuid() != 0:
        return []
    if shutil.which("setpriv") is None:
        pytest.skip(f"as root, the test needs setpriv to {what} as another user")
    return ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups"]


def folder_for(as_user: list[str], tmp_path: Path) -> Path:
    """A fresh folder the other user can reach (under /tmp: pytest's own is private to root)."""
    return Path(tempfile.mkdtemp(dir="/tmp" if as_user else tmp_path))

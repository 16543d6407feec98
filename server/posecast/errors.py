"""The one error hierarchy of posecast.

Every error posecast raises on purpose derives from :class:`PosecastError`. Each
class has a stable ``code`` (a short upper-case string). Errors a client can cause
map one-to-one onto the wire error codes listed in ``proto/``; errors from local
tools (data preparation, training) use codes of their own so logs stay greppable.

    PosecastError                     code
    ├── ConfigError                   CONFIG_INVALID
    ├── ModelError                    MODEL_INVALID    (path)
    └── DataError                     DATA_INVALID
        ├── BvhError                  BVH_INVALID      (file, line)
        ├── RigError                  RIG_UNKNOWN      (file, missing joints)
        └── DatasetError              DATASET_INVALID  (path)

Errors carry structured fields (never only a formatted string), so a caller can
log or serialise them without parsing the message.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path


class PosecastError(Exception):
    """Base of every deliberate posecast error."""

    code = "INTERNAL"

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class ConfigError(PosecastError):
    """A configuration value is missing, malformed or out of range."""

    code = "CONFIG_INVALID"


class ModelError(PosecastError):
    """A model artifact is missing, unreadable or does not match this code."""

    code = "MODEL_INVALID"

    def __init__(self, message: str, *, path: str | Path | None = None):
        self.path = str(path) if path is not None else None
        super().__init__((self.path + ": " if self.path else "") + message)


class DataError(PosecastError):
    """Motion data could not be read or converted."""

    code = "DATA_INVALID"


class BvhError(DataError):
    """A BVH file is corrupt, truncated or not BVH at all.

    ``file`` names the file and ``line`` (1-based) the line where the problem was
    found, when one applies.
    """

    code = "BVH_INVALID"

    def __init__(self, message: str, *, file: str | Path | None = None, line: int | None = None):
        self.file = str(file) if file is not None else None
        self.line = line
        where = ""
        if self.file is not None:
            where = self.file + (f":{line}" if line is not None else "")
            where += ": "
        super().__init__(where + message)
        self.detail = message


class RigError(DataError):
    """No declared rig matches a file's skeleton, or a mapped joint is missing."""

    code = "RIG_UNKNOWN"

    def __init__(
        self,
        message: str,
        *,
        file: str | Path | None = None,
        missing_joints: Sequence[str] = (),
    ):
        self.file = str(file) if file is not None else None
        self.missing_joints = tuple(missing_joints)
        text = (self.file + ": " if self.file else "") + message
        if self.missing_joints:
            text += " (missing joints: " + ", ".join(self.missing_joints) + ")"
        super().__init__(text)


class DatasetError(DataError):
    """A prepared dataset directory is missing, incomplete or of another version."""

    code = "DATASET_INVALID"

    def __init__(self, message: str, *, path: str | Path | None = None):
        self.path = str(path) if path is not None else None
        super().__init__((self.path + ": " if self.path else "") + message)

"""The one error hierarchy of posecast.

Every error posecast raises on purpose derives from :class:`PosecastError`. Each
class has a stable ``code`` (a short upper-case string). Errors a client can cause
map one-to-one onto the wire error codes listed in ``proto/``; errors from local
tools (data preparation, training) use codes of their own so logs stay greppable.

    PosecastError                     code
    ├── ConfigError                   CONFIG_INVALID
    ├── ModelError                    MODEL_INVALID    (path)
    ├── WorkerError                   WORKER_FAILED    (worker, status)
    ├── DataError                     DATA_INVALID
    │   ├── BvhError                  BVH_INVALID      (file, line)
    │   ├── AcclaimError              ACCLAIM_INVALID  (file, line)
    │   ├── RigError                  RIG_UNKNOWN      (file, missing joints)
    │   └── DatasetError              DATASET_INVALID  (path)
    └── ProtocolError                 (one per wire code; field, ref_seq, fatal)
        ├── MalformedError            MALFORMED            fatal
        ├── TooLargeError             TOO_LARGE            fatal
        ├── UnknownTypeError          UNKNOWN_TYPE
        ├── BadFieldError             BAD_FIELD
        ├── OutOfRangeError           OUT_OF_RANGE
        ├── NotNormalisedError        NOT_NORMALISED
        ├── OutOfOrderError           OUT_OF_ORDER
        ├── DuplicateError            DUPLICATE
        ├── RateLimitedError          RATE_LIMITED
        ├── UnauthenticatedError      UNAUTHENTICATED      fatal
        ├── TokenExpiredError         TOKEN_EXPIRED        fatal
        ├── ForbiddenError            FORBIDDEN
        ├── VersionUnsupportedError   VERSION_UNSUPPORTED  fatal
        ├── LayoutUnsupportedError    LAYOUT_UNSUPPORTED   fatal
        ├── RoomFullError             ROOM_FULL            fatal
        ├── NotJoinedError            NOT_JOINED           fatal
        ├── AlreadyJoinedError        ALREADY_JOINED
        ├── NotFoundError             NOT_FOUND
        ├── CalibrationFailedError    CALIBRATION_FAILED
        ├── TimedOutError             TIMED_OUT            fatal
        ├── KickedError               KICKED               fatal
        ├── ReplacedError             REPLACED             fatal
        ├── SlowConsumerError         SLOW_CONSUMER        fatal
        ├── ServerShutdownError       SERVER_SHUTDOWN      fatal
        └── InternalError             INTERNAL

Every :class:`ProtocolError` subclass is one wire error code (``proto/errors.json``
and the table in ``proto/README.md`` list the same codes; a test keeps them in
sync). Its class name is the code in CamelCase plus ``Error``. ``fatal`` is the
default for the code; one raise can override it.

Errors carry structured fields (never only a formatted string), so a caller can
log or serialise them without parsing the message.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any


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


class WorkerError(PosecastError):
    """A serving worker process of ``posecast serve --workers N`` exited before it was
    ready (its own log says why), or a client process of ``posecast bench latency``
    failed; ``status`` is its exit status."""

    code = "WORKER_FAILED"

    def __init__(self, message: str, *, worker: int, status: int | None):
        self.worker, self.status = worker, status
        super().__init__(message)


class DataError(PosecastError):
    """Motion data could not be read or converted."""

    code = "DATA_INVALID"


class _FileError(DataError):
    """A data file problem at a place: ``file`` names the file and ``line`` (1-based)
    the line where it was found, when one applies; ``detail`` is the bare message."""

    def __init__(self, message: str, *, file: str | Path | None = None, line: int | None = None):
        self.file = str(file) if file is not None else None
        self.line = line
        where = ""
        if self.file is not None:
            where = self.file + (f":{line}" if line is not None else "")
            where += ": "
        super().__init__(where + message)
        self.detail = message


class BvhError(_FileError):
    """A BVH file is corrupt, truncated or not BVH at all."""

    code = "BVH_INVALID"


class AcclaimError(_FileError):
    """An Acclaim ASF skeleton or AMC motion file (the ``.asf``/``.asx`` or the
    ``.amc``) is corrupt, truncated or inconsistent."""

    code = "ACCLAIM_INVALID"


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


# --- Wire protocol -----------------------------------------------------------------


class ProtocolError(PosecastError):
    """A message broke protocol v1, or the server refuses it (``proto/README.md``).

    Attributes:
        code: the stable wire code (class attribute, one per subclass).
        fatal: whether the connection ends after this error (the class default
            unless the raise overrides it).
        field: the offending field as a path (``"trackers[2]"``), when one applies.
        ref_seq: the ``seq`` of the frame that caused the error, when known.
    """

    code = "INTERNAL"
    fatal = False

    def __init__(
        self,
        message: str,
        *,
        field: str | None = None,
        ref_seq: int | None = None,
        fatal: bool | None = None,
    ) -> None:
        super().__init__(message)
        self.field = field
        self.ref_seq = ref_seq
        if fatal is not None:
            self.fatal = fatal

    @staticmethod
    def for_code(code: str) -> type[ProtocolError]:
        """The class of a wire code; :class:`ProtocolError` itself for an unknown one."""
        return _PROTOCOL_ERRORS.get(code, ProtocolError)


class MalformedError(ProtocolError):
    """Not one well-formed msgpack map: bad bytes, truncated, trailing data, an ext
    type, a non-string key, or nested deeper than the limit."""

    code = "MALFORMED"
    fatal = True


class TooLargeError(ProtocolError):
    """The message, or one string, bin, array or map inside it, is over its size limit."""

    code = "TOO_LARGE"
    fatal = True


class UnknownTypeError(ProtocolError):
    """The ``type`` names no message of the connection's protocol version (v1 or v2)."""

    code = "UNKNOWN_TYPE"


class BadFieldError(ProtocolError):
    """A field is missing, of the wrong msgpack type or shape, or not an allowed value."""

    code = "BAD_FIELD"


class OutOfRangeError(ProtocolError):
    """A number is not finite or outside its range, or a string's length is outside its bounds."""

    code = "OUT_OF_RANGE"


class NotNormalisedError(ProtocolError):
    """A quaternion's norm is off 1 by more than the tolerance (1e-3)."""

    code = "NOT_NORMALISED"


class OutOfOrderError(ProtocolError):
    """A frame's ``seq`` is older than one already received; the frame was dropped."""

    code = "OUT_OF_ORDER"


class DuplicateError(ProtocolError):
    """A frame repeats the ``seq`` of the last one received; it was dropped."""

    code = "DUPLICATE"


class RateLimitedError(ProtocolError):
    """Messages arrive faster than the announced limit; the excess was dropped."""

    code = "RATE_LIMITED"


class UnauthenticatedError(ProtocolError):
    """The ``hello`` token is missing, malformed or its signature does not verify, or a
    session with it ended with ``bye`` or a kick (refused until the token expires)."""

    code = "UNAUTHENTICATED"
    fatal = True

    def __init__(self, message: str, *, reason: str = "invalid", **kw: Any) -> None:
        """``reason``: a stable slug of why (``posecast.online.auth.tokens.REASONS``),
        the label the refusal is counted under in ``posecast_token_refusals_total``."""
        super().__init__(message, **kw)
        self.reason = reason


class TokenExpiredError(ProtocolError):
    """The token verified but has expired (or is not valid yet)."""

    code = "TOKEN_EXPIRED"
    fatal = True

    def __init__(self, message: str, *, reason: str = "expired", **kw: Any) -> None:
        """``reason``: ``expired`` or ``not_yet_valid`` (as for UnauthenticatedError)."""
        super().__init__(message, **kw)
        self.reason = reason


class ForbiddenError(ProtocolError):
    """The token's role or rooms do not allow this message or this room."""

    code = "FORBIDDEN"


class VersionUnsupportedError(ProtocolError):
    """``hello.version`` is not the connection's version: 1 on ``posecast.v1``, 2 on
    ``posecast.v2``."""

    code = "VERSION_UNSUPPORTED"
    fatal = True


class LayoutUnsupportedError(ProtocolError):
    """The tracker ``layout`` is known but this server does not serve it (``--layouts``)."""

    code = "LAYOUT_UNSUPPORTED"
    fatal = True


class RoomFullError(ProtocolError):
    """The room already holds its maximum number of players."""

    code = "ROOM_FULL"
    fatal = True


class NotJoinedError(ProtocolError):
    """A message other than ``hello`` arrived before the ``welcome``."""

    code = "NOT_JOINED"
    fatal = True


class AlreadyJoinedError(ProtocolError):
    """A second ``hello`` on a connection that has already joined."""

    code = "ALREADY_JOINED"


class NotFoundError(ProtocolError):
    """A ``selector`` or ``kick`` names a player that is not in a watched room."""

    code = "NOT_FOUND"


class CalibrationFailedError(ProtocolError):
    """A ``calibrate`` was well formed but implausible (e.g. the T-pose head height)."""

    code = "CALIBRATION_FAILED"


class TimedOutError(ProtocolError):
    """No ``hello`` in time after connecting, or no message for too long."""

    code = "TIMED_OUT"
    fatal = True


class KickedError(ProtocolError):
    """A backend removed this player (``kick``); the message carries its reason."""

    code = "KICKED"
    fatal = True


class ReplacedError(ProtocolError):
    """The same player joined again on another connection, which took over."""

    code = "REPLACED"
    fatal = True


class SlowConsumerError(ProtocolError):
    """The client has not read its socket for too long; the server gives up on it."""

    code = "SLOW_CONSUMER"
    fatal = True


class ServerShutdownError(ProtocolError):
    """The server is going away; clients should reconnect later (with back-off)."""

    code = "SERVER_SHUTDOWN"
    fatal = True


class InternalError(ProtocolError):
    """The server failed on a valid message; the message was dropped."""

    code = "INTERNAL"


_PROTOCOL_ERRORS: dict[str, type[ProtocolError]] = {
    cls.code: cls for cls in ProtocolError.__subclasses__()
}

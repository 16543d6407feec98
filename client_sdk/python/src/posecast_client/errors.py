"""The one error hierarchy of the posecast client SDK.

Every error the SDK raises on purpose derives from :class:`PosecastClientError`.
Wire errors (an ``error`` message from the server, or a message this SDK's codec
refuses) are :class:`ProtocolError` subclasses, exactly one per code of
``proto/errors.json``; a test keeps this table and that file in sync.

    PosecastClientError
    ├── ClientClosedError             the client was closed; it sends nothing more
    ├── ConfigInvalidError            a URL or token the client cannot use (also a ValueError)
    ├── ConnectionLostError           the connection dropped without an error  retryable
    │   └── ConnectFailedError        no WebSocket opened at url (refused, DNS, TLS, HTTP 429/503)
    ├── TokenProviderError            the token function raised (its error as cause)  retryable
    ├── BvhError                      a BVH file cannot be read (file, line)
    ├── RecordingError                a file is not a posecast recording (also a ValueError)
    └── ProtocolError                 one per wire code: code, fatal, field, ref_seq
        ├── MalformedError            MALFORMED            fatal   decoder
        ├── TooLargeError             TOO_LARGE            fatal   decoder
        ├── UnknownTypeError          UNKNOWN_TYPE                 decoder
        ├── BadFieldError             BAD_FIELD                    decoder
        ├── OutOfRangeError           OUT_OF_RANGE                 decoder
        ├── NotNormalisedError        NOT_NORMALISED               decoder
        ├── OutOfOrderError           OUT_OF_ORDER
        ├── DuplicateError            DUPLICATE
        ├── RateLimitedError          RATE_LIMITED
        ├── UnauthenticatedError      UNAUTHENTICATED      fatal
        ├── TokenExpiredError         TOKEN_EXPIRED        fatal
        ├── ForbiddenError            FORBIDDEN
        ├── VersionUnsupportedError   VERSION_UNSUPPORTED  fatal   decoder
        ├── LayoutUnsupportedError    LAYOUT_UNSUPPORTED   fatal
        ├── RoomFullError             ROOM_FULL            fatal
        ├── NotJoinedError            NOT_JOINED           fatal
        ├── AlreadyJoinedError        ALREADY_JOINED
        ├── NotFoundError             NOT_FOUND
        ├── CalibrationFailedError    CALIBRATION_FAILED
        ├── TimedOutError             TIMED_OUT            fatal   retryable
        ├── KickedError               KICKED               fatal
        ├── ReplacedError             REPLACED             fatal
        ├── SlowConsumerError         SLOW_CONSUMER        fatal   retryable
        ├── ServerShutdownError       SERVER_SHUTDOWN      fatal   retryable
        └── InternalError             INTERNAL                     retryable

``fatal`` is the code's usual value; one ``error`` message may override it (the
message is authoritative). ``retryable`` says whether the client reconnects and
rejoins after the error ended a session: a server going away or giving up on a slow
or silent connection is worth another try; a refused token, a kick or a takeover by
another connection is not. A code this SDK does not know (a newer server) maps to
:class:`ProtocolError` itself, with ``code`` set.
"""

from __future__ import annotations

from typing import ClassVar


class PosecastClientError(Exception):
    """Base of every deliberate posecast client error."""

    def __init__(self, message: str) -> None:
        super().__init__(message)
        self.message = message


class ClientClosedError(PosecastClientError):
    """The client was closed (or its session ended for good); it sends nothing more."""


class ConnectionLostError(PosecastClientError):
    """The connection dropped (or the server said ``bye``) without a fatal error.

    The client reconnects after it; it is raised only when reconnecting is off or
    has given up. ``__cause__`` holds the transport's own exception, if any.
    """

    retryable: ClassVar[bool] = True


class ConfigInvalidError(PosecastClientError, ValueError):
    """An argument the client cannot use, refused before it dials: a URL that is not
    ``ws://`` or ``wss://`` with a host, or no token (``None``, empty, not a string).
    Never retried. ``hint`` says what to pass instead; it ends the message too
    (``reason`` is the message without it). A ``ValueError`` too, as the client raised
    one before this class."""

    retryable: ClassVar[bool] = False

    def __init__(self, message: str, *, hint: str) -> None:
        super().__init__(f"{message} (hint: {hint})")
        self.reason = message  # the message without its hint
        self.hint = hint


class TokenProviderError(PosecastClientError):
    """The token function (``connect``'s ``token`` when callable) raised: the backend's
    token endpoint may be briefly down. ``__cause__`` is what it raised.

    Retryable: a rejoin calls the function again, up to ``max_reconnect_attempts``,
    after which ``events()`` raises this error. The first ``join`` is not retried. A
    function that returns no token (``None``, an empty string) is a programming error:
    :class:`ConfigInvalidError`, never retried.
    """

    retryable: ClassVar[bool] = True


class ConnectFailedError(ConnectionLostError):
    """No WebSocket session opened at ``url``: the connection was refused or timed out,
    the host name did not resolve, TLS failed, or the server refused the upgrade
    (``status``: its HTTP status, such as 429 when this address connects too often or
    503 while the server is not ready). ``reason`` says which, ``hint`` what to check
    (both are in the message); ``__cause__`` is the transport's own exception.

    Retryable, as the lost connection it replaces: reconnects go on after it (the
    first :func:`~posecast_client.connect` is not retried).
    """

    def __init__(self, url: str, reason: str, *, hint: str, status: int | None = None) -> None:
        super().__init__(f"could not connect to {url}: {reason} (hint: {hint})")
        self.url, self.reason, self.hint, self.status = url, reason, hint, status


class RecordingError(PosecastClientError, ValueError):
    """A file is not a posecast recording, or one cut short or corrupt (a
    ``ValueError`` too, as :func:`~posecast_client.recording.read_recording` raised
    before this class)."""


class BvhError(PosecastClientError):
    """A BVH file is corrupt, truncated or not BVH at all. ``line`` is 1-based."""

    def __init__(self, message: str, *, file: str | None = None, line: int | None = None) -> None:
        self.file, self.line = file, line
        where = "" if file is None else file + ("" if line is None else f":{line}") + ": "
        super().__init__(where + message)


class ProtocolError(PosecastClientError):
    """A message broke protocol v1, or the server refused one (``proto/README.md``).

    Attributes:
        code: the wire code (``"BAD_FIELD"``); one subclass per code.
        fatal: whether the connection ends after this error.
        decoder: whether a decoder itself produces this code (class attribute).
        retryable: whether the client reconnects after it ended a session.
        field: path of the offending field (``"trackers[2]"``), when one applies.
        ref_seq: ``seq`` of the frame that caused it, when known.
    """

    code: str = "INTERNAL"
    fatal: bool = False
    decoder: ClassVar[bool] = False
    retryable: ClassVar[bool] = False

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

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.code}, {self.message!r}, field={self.field!r})"

    @staticmethod
    def from_wire(
        code: str,
        message: str,
        *,
        fatal: bool | None = None,
        field: str | None = None,
        ref_seq: int | None = None,
    ) -> ProtocolError:
        """The typed exception for a wire code (:class:`ProtocolError` for an unknown one)."""
        exc = ERRORS.get(code, ProtocolError)(message, field=field, ref_seq=ref_seq, fatal=fatal)
        exc.code = code
        return exc


class MalformedError(ProtocolError):
    """Not one well-formed msgpack map: bad bytes, truncated, trailing data, an ext type, a non-string key, or nested deeper than the limit."""  # noqa: E501

    code = "MALFORMED"
    fatal = True
    decoder = True


class TooLargeError(ProtocolError):
    """The message, or one string, bin, array or map inside it, is over its size limit."""

    code = "TOO_LARGE"
    fatal = True
    decoder = True


class UnknownTypeError(ProtocolError):
    """The type names no message of the connection's protocol version (v1 or v2)."""

    code = "UNKNOWN_TYPE"
    decoder = True


class BadFieldError(ProtocolError):
    """A field is missing, of the wrong msgpack type or shape, or not an allowed value."""

    code = "BAD_FIELD"
    decoder = True


class OutOfRangeError(ProtocolError):
    """A number is not finite or outside its range, or a string's length is outside its bounds."""

    code = "OUT_OF_RANGE"
    decoder = True


class NotNormalisedError(ProtocolError):
    """A quaternion's norm is off 1 by more than the tolerance (1e-3)."""

    code = "NOT_NORMALISED"
    decoder = True


class OutOfOrderError(ProtocolError):
    """A frame's seq is older than one already received; the frame was dropped."""

    code = "OUT_OF_ORDER"


class DuplicateError(ProtocolError):
    """A frame repeats the seq of the last one received; it was dropped."""

    code = "DUPLICATE"


class RateLimitedError(ProtocolError):
    """Messages arrive faster than the announced limit; the excess was dropped."""

    code = "RATE_LIMITED"


class UnauthenticatedError(ProtocolError):
    """The hello token is missing, malformed or its signature does not verify, or a
    session with it ended with bye or a kick (refused until the token expires)."""

    code = "UNAUTHENTICATED"
    fatal = True


class TokenExpiredError(ProtocolError):
    """The token verified but has expired (or is not valid yet)."""

    code = "TOKEN_EXPIRED"
    fatal = True


class ForbiddenError(ProtocolError):
    """The token's role or rooms do not allow this message or this room."""

    code = "FORBIDDEN"


class VersionUnsupportedError(ProtocolError):
    """hello.version is not the connection's version: 1 on posecast.v1, 2 on posecast.v2."""

    code = "VERSION_UNSUPPORTED"
    fatal = True
    decoder = True


class LayoutUnsupportedError(ProtocolError):
    """The tracker layout is known but this server does not serve it (--layouts)."""

    code = "LAYOUT_UNSUPPORTED"
    fatal = True


class RoomFullError(ProtocolError):
    """The room already holds its maximum number of players."""

    code = "ROOM_FULL"
    fatal = True


class NotJoinedError(ProtocolError):
    """A message other than hello arrived before the welcome."""

    code = "NOT_JOINED"
    fatal = True


class AlreadyJoinedError(ProtocolError):
    """A second hello on a connection that has already joined."""

    code = "ALREADY_JOINED"


class NotFoundError(ProtocolError):
    """A selector or kick names a player that is not in a watched room."""

    code = "NOT_FOUND"


class CalibrationFailedError(ProtocolError):
    """A calibrate was well formed but implausible (e.g. the T-pose head height)."""

    code = "CALIBRATION_FAILED"


class TimedOutError(ProtocolError):
    """No hello in time after connecting, or no message for too long."""

    code = "TIMED_OUT"
    fatal = True
    retryable = True


class KickedError(ProtocolError):
    """A backend removed this player (kick); the message carries its reason."""

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
    retryable = True


class ServerShutdownError(ProtocolError):
    """The server is going away; clients should reconnect later (with back-off)."""

    code = "SERVER_SHUTDOWN"
    fatal = True
    retryable = True


class InternalError(ProtocolError):
    """The server failed on a valid message; the message was dropped."""

    code = "INTERNAL"
    retryable = True


# Wire code -> class, in the order of proto/errors.json.
ERRORS: dict[str, type[ProtocolError]] = {cls.code: cls for cls in ProtocolError.__subclasses__()}

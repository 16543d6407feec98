// The one error hierarchy of the posecast C# SDK.
//
// Every exception the SDK throws on purpose derives from PosecastException. Wire
// errors (an `error` message from the server, or a message this SDK's codec refuses)
// are ProtocolException subclasses, exactly one per code of proto/errors.json; a test
// keeps this table and that file in step.
//
//   PosecastException
//   ├── ClientClosedException          the client was closed; it sends nothing more
//   ├── ConfigInvalidException         a URL or token the client cannot use, refused before dialing
//   ├── ConnectionLostException        the connection dropped without an error  retryable
//   │   └── ConnectFailedException     no WebSocket opened at Url (refused, DNS, TLS, HTTP 429/503)
//   ├── TokenProviderException         the TokenProvider threw (InnerException)  retryable
//   └── ProtocolException              one per wire code: Code, Fatal, Field, RefSeq
//       ├── MalformedException         MALFORMED            fatal   decoder
//       ├── TooLargeException          TOO_LARGE            fatal   decoder
//       ├── UnknownTypeException       UNKNOWN_TYPE                 decoder
//       ├── BadFieldException          BAD_FIELD                    decoder
//       ├── OutOfRangeException        OUT_OF_RANGE                 decoder
//       ├── NotNormalisedException     NOT_NORMALISED               decoder
//       ├── OutOfOrderException        OUT_OF_ORDER
//       ├── DuplicateException         DUPLICATE
//       ├── RateLimitedException       RATE_LIMITED
//       ├── UnauthenticatedException   UNAUTHENTICATED      fatal
//       ├── TokenExpiredException      TOKEN_EXPIRED        fatal
//       ├── ForbiddenException         FORBIDDEN
//       ├── VersionUnsupportedException VERSION_UNSUPPORTED fatal   decoder
//       ├── LayoutUnsupportedException LAYOUT_UNSUPPORTED   fatal
//       ├── RoomFullException          ROOM_FULL            fatal
//       ├── NotJoinedException         NOT_JOINED           fatal
//       ├── AlreadyJoinedException     ALREADY_JOINED
//       ├── NotFoundException          NOT_FOUND
//       ├── CalibrationFailedException CALIBRATION_FAILED
//       ├── TimedOutException          TIMED_OUT            fatal   retryable
//       ├── KickedException            KICKED               fatal
//       ├── ReplacedException          REPLACED             fatal
//       ├── SlowConsumerException      SLOW_CONSUMER        fatal   retryable
//       ├── ServerShutdownException    SERVER_SHUTDOWN      fatal   retryable
//       └── InternalException          INTERNAL                     retryable
//
// Fatal is the code's usual value; one `error` message may override it (the message
// is authoritative). Retryable says whether the client reconnects and rejoins after
// the error ended a session, as in the Python and TypeScript SDKs. A code this SDK
// does not know (a newer server) maps to ProtocolException itself, with Code set.

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    /// <summary>Base of every deliberate posecast client error.</summary>
    public class PosecastException : Exception
    {
        public PosecastException(string message) : base(message) { }
        public PosecastException(string message, Exception inner) : base(message, inner) { }

        /// <summary>Whether the client reconnects after this ended a session.</summary>
        public virtual bool Retryable { get { return false; } }
    }

    /// <summary>The client was closed (or its session ended for good).</summary>
    public sealed class ClientClosedException : PosecastException
    {
        public ClientClosedException(string message) : base(message) { }
    }

    /// <summary>
    /// An argument the client cannot use, refused before it dials: a URL that is not ws://
    /// or wss:// with a host, or no token (null, empty) without a TokenProvider. Never
    /// retried. Hint says what to pass instead; the message ends with it.
    /// </summary>
    public sealed class ConfigInvalidException : PosecastException
    {
        public readonly string Hint;

        public ConfigInvalidException(string message, string hint) : base(message + " (hint: " + hint + ")")
        {
            Hint = hint;
        }
    }

    /// <summary>The connection dropped (or the server said bye) without a fatal error.</summary>
    public class ConnectionLostException : PosecastException
    {
        public ConnectionLostException(string message) : base(message) { }
        public ConnectionLostException(string message, Exception inner) : base(message, inner) { }
        public override bool Retryable { get { return true; } }
    }

    /// <summary>
    /// The TokenProvider threw: the backend's token endpoint may be briefly down.
    /// InnerException is what it threw. Retryable: a rejoin calls it again, up to
    /// MaxReconnectAttempts, after which TryGetEvent throws this; the first JoinAsync
    /// throws it (not retried). A TokenProvider that returns no token is a
    /// ConfigInvalidException, never retried.
    /// </summary>
    public sealed class TokenProviderException : PosecastException
    {
        public TokenProviderException(string message, Exception inner) : base(message, inner) { }
        public override bool Retryable { get { return true; } }
    }

    /// <summary>
    /// No WebSocket opened at Url: the connection was refused or timed out, the host name
    /// did not resolve, TLS failed, or the server refused the upgrade (Status: its HTTP
    /// status where the runtime says it, 429 when this address connects too often, 503
    /// while the server starts or is full). Reason says which, Hint what to check (both
    /// are in the message); InnerException is the runtime's own. Retryable: reconnects go
    /// on after it (the first ConnectAsync is not retried).
    /// </summary>
    public sealed class ConnectFailedException : ConnectionLostException
    {
        public readonly string Url;
        public readonly string Reason;
        public readonly string Hint;
        public readonly int? Status;

        public ConnectFailedException(string url, string reason, string hint, int? status, Exception inner)
            : base("could not connect to " + url + ": " + reason + " (hint: " + hint + ")", inner)
        {
            Url = url; Reason = reason; Hint = hint; Status = status;
        }
    }

    /// <summary>One row of proto/errors.json, plus whether the SDK retries after it.</summary>
    public sealed class ErrorCode
    {
        public readonly string Code;
        public readonly bool Fatal;
        public readonly bool Decoder;
        public readonly bool Retryable;
        internal readonly Func<string, ProtocolException> Make;

        internal ErrorCode(string code, bool fatal, bool decoder, bool retryable,
                           Func<string, ProtocolException> make)
        {
            Code = code; Fatal = fatal; Decoder = decoder; Retryable = retryable; Make = make;
        }
    }

    /// <summary>
    /// A message broke the protocol, or the server refused one (proto/README.md).
    /// </summary>
    public class ProtocolException : PosecastException
    {
        /// <summary>The wire code ("BAD_FIELD").</summary>
        public string Code { get; internal set; }
        /// <summary>Whether the connection ends after this error.</summary>
        public bool Fatal { get; internal set; }
        /// <summary>Path of the offending field ("trackers[2]"), or null.</summary>
        public string Field { get; internal set; }
        /// <summary>seq of the frame that caused it, or null.</summary>
        public long? RefSeq { get; internal set; }

        public ProtocolException(string code, string message) : base(message)
        {
            Code = code;
            ErrorCode row;
            Fatal = ErrorCodes.ByCode.TryGetValue(code, out row) && row.Fatal;
        }

        public override bool Retryable
        {
            get { ErrorCode row; return ErrorCodes.ByCode.TryGetValue(Code, out row) && row.Retryable; }
        }

        internal ProtocolException At(string field, long? refSeq = null)
        {
            Field = field;
            RefSeq = refSeq;
            return this;
        }

        /// <summary>The typed exception for a wire code (ProtocolException for an unknown one).</summary>
        public static ProtocolException FromWire(string code, string message, bool? fatal = null,
                                                 string field = null, long? refSeq = null)
        {
            ErrorCode row;
            var exc = ErrorCodes.ByCode.TryGetValue(code, out row)
                ? row.Make(message) : new ProtocolException(code, message);
            if (fatal.HasValue) exc.Fatal = fatal.Value;
            exc.Field = field;
            exc.RefSeq = refSeq;
            return exc;
        }

        public override string ToString()
        {
            return GetType().Name + "(" + Code + ", " + Message + (Field == null ? "" : ", field=" + Field) + ")";
        }
    }

    public sealed class MalformedException : ProtocolException { public MalformedException(string m) : base("MALFORMED", m) { } }
    public sealed class TooLargeException : ProtocolException { public TooLargeException(string m) : base("TOO_LARGE", m) { } }
    public sealed class UnknownTypeException : ProtocolException { public UnknownTypeException(string m) : base("UNKNOWN_TYPE", m) { } }
    public sealed class BadFieldException : ProtocolException { public BadFieldException(string m) : base("BAD_FIELD", m) { } }
    public sealed class OutOfRangeException : ProtocolException { public OutOfRangeException(string m) : base("OUT_OF_RANGE", m) { } }
    public sealed class NotNormalisedException : ProtocolException { public NotNormalisedException(string m) : base("NOT_NORMALISED", m) { } }
    public sealed class OutOfOrderException : ProtocolException { public OutOfOrderException(string m) : base("OUT_OF_ORDER", m) { } }
    public sealed class DuplicateException : ProtocolException { public DuplicateException(string m) : base("DUPLICATE", m) { } }
    public sealed class RateLimitedException : ProtocolException { public RateLimitedException(string m) : base("RATE_LIMITED", m) { } }
    public sealed class UnauthenticatedException : ProtocolException { public UnauthenticatedException(string m) : base("UNAUTHENTICATED", m) { } }
    public sealed class TokenExpiredException : ProtocolException { public TokenExpiredException(string m) : base("TOKEN_EXPIRED", m) { } }
    public sealed class ForbiddenException : ProtocolException { public ForbiddenException(string m) : base("FORBIDDEN", m) { } }
    public sealed class VersionUnsupportedException : ProtocolException { public VersionUnsupportedException(string m) : base("VERSION_UNSUPPORTED", m) { } }
    public sealed class LayoutUnsupportedException : ProtocolException { public LayoutUnsupportedException(string m) : base("LAYOUT_UNSUPPORTED", m) { } }
    public sealed class RoomFullException : ProtocolException { public RoomFullException(string m) : base("ROOM_FULL", m) { } }
    public sealed class NotJoinedException : ProtocolException { public NotJoinedException(string m) : base("NOT_JOINED", m) { } }
    public sealed class AlreadyJoinedException : ProtocolException { public AlreadyJoinedException(string m) : base("ALREADY_JOINED", m) { } }
    public sealed class NotFoundException : ProtocolException { public NotFoundException(string m) : base("NOT_FOUND", m) { } }
    public sealed class CalibrationFailedException : ProtocolException { public CalibrationFailedException(string m) : base("CALIBRATION_FAILED", m) { } }
    public sealed class TimedOutException : ProtocolException { public TimedOutException(string m) : base("TIMED_OUT", m) { } }
    public sealed class KickedException : ProtocolException { public KickedException(string m) : base("KICKED", m) { } }
    public sealed class ReplacedException : ProtocolException { public ReplacedException(string m) : base("REPLACED", m) { } }
    public sealed class SlowConsumerException : ProtocolException { public SlowConsumerException(string m) : base("SLOW_CONSUMER", m) { } }
    public sealed class ServerShutdownException : ProtocolException { public ServerShutdownException(string m) : base("SERVER_SHUTDOWN", m) { } }
    public sealed class InternalException : ProtocolException { public InternalException(string m) : base("INTERNAL", m) { } }

    /// <summary>Every wire code, in the order of proto/errors.json.</summary>
    public static class ErrorCodes
    {
        public static readonly IList<ErrorCode> All = new List<ErrorCode>
        {
            //            code                   fatal  decoder retryable
            new ErrorCode("MALFORMED",           true,  true,  false, m => new MalformedException(m)),
            new ErrorCode("TOO_LARGE",           true,  true,  false, m => new TooLargeException(m)),
            new ErrorCode("UNKNOWN_TYPE",        false, true,  false, m => new UnknownTypeException(m)),
            new ErrorCode("BAD_FIELD",           false, true,  false, m => new BadFieldException(m)),
            new ErrorCode("OUT_OF_RANGE",        false, true,  false, m => new OutOfRangeException(m)),
            new ErrorCode("NOT_NORMALISED",      false, true,  false, m => new NotNormalisedException(m)),
            new ErrorCode("OUT_OF_ORDER",        false, false, false, m => new OutOfOrderException(m)),
            new ErrorCode("DUPLICATE",           false, false, false, m => new DuplicateException(m)),
            new ErrorCode("RATE_LIMITED",        false, false, false, m => new RateLimitedException(m)),
            new ErrorCode("UNAUTHENTICATED",     true,  false, false, m => new UnauthenticatedException(m)),
            new ErrorCode("TOKEN_EXPIRED",       true,  false, false, m => new TokenExpiredException(m)),
            new ErrorCode("FORBIDDEN",           false, false, false, m => new ForbiddenException(m)),
            new ErrorCode("VERSION_UNSUPPORTED", true,  true,  false, m => new VersionUnsupportedException(m)),
            new ErrorCode("LAYOUT_UNSUPPORTED",  true,  false, false, m => new LayoutUnsupportedException(m)),
            new ErrorCode("ROOM_FULL",           true,  false, false, m => new RoomFullException(m)),
            new ErrorCode("NOT_JOINED",          true,  false, false, m => new NotJoinedException(m)),
            new ErrorCode("ALREADY_JOINED",      false, false, false, m => new AlreadyJoinedException(m)),
            new ErrorCode("NOT_FOUND",           false, false, false, m => new NotFoundException(m)),
            new ErrorCode("CALIBRATION_FAILED",  false, false, false, m => new CalibrationFailedException(m)),
            new ErrorCode("TIMED_OUT",           true,  false, true,  m => new TimedOutException(m)),
            new ErrorCode("KICKED",              true,  false, false, m => new KickedException(m)),
            new ErrorCode("REPLACED",            true,  false, false, m => new ReplacedException(m)),
            new ErrorCode("SLOW_CONSUMER",       true,  false, true,  m => new SlowConsumerException(m)),
            new ErrorCode("SERVER_SHUTDOWN",     true,  false, true,  m => new ServerShutdownException(m)),
            new ErrorCode("INTERNAL",            false, false, true,  m => new InternalException(m)),
        }.AsReadOnly();

        public static readonly IDictionary<string, ErrorCode> ByCode = Index();

        private static IDictionary<string, ErrorCode> Index()
        {
            var d = new Dictionary<string, ErrorCode>();
            foreach (var row in All) d[row.Code] = row;
            return d;
        }

        internal static ProtocolException Malformed(string m) { return new MalformedException(m); }
        internal static ProtocolException TooLarge(string m) { return new TooLargeException(m); }
        internal static ProtocolException BadField(string field, string m) { return new BadFieldException(m).At(field); }
        internal static ProtocolException OutOfRange(string field, string m) { return new OutOfRangeException(m).At(field); }
        internal static ProtocolException NotNormalised(string field, string m) { return new NotNormalisedException(m).At(field); }
    }
}

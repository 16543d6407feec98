/**
 * The one error hierarchy of the posecast TypeScript SDK.
 *
 * Every error the SDK throws on purpose derives from {@link PosecastError}. Errors
 * that travel on the wire are {@link ProtocolError}s, one subclass per code of
 * `proto/errors.json` (a test keeps this table and that file in sync); the class
 * name is the code in CamelCase plus `Error`, as in the Python server's
 * `posecast/errors.py`.
 *
 * ```text
 * PosecastError                     code
 * ├── ConfigInvalidError            CONFIG_INVALID     (hint; local: a URL or token refused before dialing)
 * ├── ConnectionClosedError         CONNECTION_CLOSED  (closeCode, closeReason; local)
 * │   └── ConnectFailedError        CONNECTION_CLOSED  (url, reason, hint, status: no socket opened)
 * ├── TokenProviderError            TOKEN_PROVIDER_FAILED (cause: the token function threw; local, retried)
 * └── ProtocolError                 (one per wire code; field, refSeq, fatal)
 *     ├── MalformedError            MALFORMED            fatal
 *     ├── TooLargeError             TOO_LARGE            fatal
 *     ├── UnknownTypeError          UNKNOWN_TYPE
 *     ├── BadFieldError             BAD_FIELD
 *     ├── OutOfRangeError           OUT_OF_RANGE
 *     ├── NotNormalisedError        NOT_NORMALISED
 *     ├── OutOfOrderError           OUT_OF_ORDER
 *     ├── DuplicateError            DUPLICATE
 *     ├── RateLimitedError          RATE_LIMITED
 *     ├── UnauthenticatedError      UNAUTHENTICATED      fatal
 *     ├── TokenExpiredError         TOKEN_EXPIRED        fatal
 *     ├── ForbiddenError            FORBIDDEN
 *     ├── VersionUnsupportedError   VERSION_UNSUPPORTED  fatal
 *     ├── LayoutUnsupportedError    LAYOUT_UNSUPPORTED   fatal
 *     ├── RoomFullError             ROOM_FULL            fatal
 *     ├── NotJoinedError            NOT_JOINED           fatal
 *     ├── AlreadyJoinedError        ALREADY_JOINED
 *     ├── NotFoundError             NOT_FOUND
 *     ├── CalibrationFailedError    CALIBRATION_FAILED
 *     ├── TimedOutError             TIMED_OUT            fatal
 *     ├── KickedError               KICKED               fatal
 *     ├── ReplacedError             REPLACED             fatal
 *     ├── SlowConsumerError         SLOW_CONSUMER        fatal
 *     ├── ServerShutdownError       SERVER_SHUTDOWN      fatal
 *     └── InternalError             INTERNAL
 * ```
 *
 * `fatal` on a class is the code's default; an `error` message from the server
 * carries the authoritative value, and {@link errorFromMessage} keeps it. Errors carry
 * structured fields, so callers branch on `instanceof` or `code`, never on text.
 */

/** Base of every deliberate posecast error. */
export class PosecastError extends Error {
  /** Stable upper-case code: a wire code for protocol errors, a local one otherwise. */
  readonly code: string;

  constructor(code: string, message: string, options?: { readonly cause?: unknown }) {
    super(message, options);
    this.code = code;
    this.name = new.target.name;
  }
}

/**
 * An argument the client cannot use, refused before it dials: a URL that is not
 * `ws://` or `wss://` with a host, or no token (`undefined` from an unset environment
 * variable, an empty string, a value that is neither a string nor a function). Never
 * retried. `hint` says what to pass instead; the message ends with it. Not a wire code.
 */
export class ConfigInvalidError extends PosecastError {
  readonly hint: string;

  constructor(message: string, hint: string, options?: { readonly cause?: unknown }) {
    super("CONFIG_INVALID", `${message} (hint: ${hint})`, options);
    this.hint = hint;
  }
}

/**
 * The socket closed, or could not be opened, before the operation finished
 * (connect, join, a fatal end without an `error` message). Not a wire code.
 */
export class ConnectionClosedError extends PosecastError {
  /** WebSocket close code (1006: no close frame, e.g. the network went away). */
  readonly closeCode: number;
  readonly closeReason: string;

  constructor(
    message: string,
    closeCode = 1006,
    closeReason = "",
    options?: { readonly cause?: unknown },
  ) {
    super("CONNECTION_CLOSED", message, options);
    this.closeCode = closeCode;
    this.closeReason = closeReason;
  }
}

/**
 * No WebSocket opened at `url`: refused, a host name that does not resolve, TLS
 * failing, no handshake in `timeoutS`, or the server refusing the upgrade (`status`:
 * 429 when this address connects too often, 503 while the server starts or is full;
 * known where the WebSocket class says, as `ws` does). `reason` says which where the
 * host tells (a browser tells nothing), `hint` what to check; `cause` is the host's
 * own error, if any. A {@link ConnectionClosedError}: reconnects retry it.
 */
export class ConnectFailedError extends ConnectionClosedError {
  readonly url: string;
  readonly reason: string;
  readonly hint: string;
  readonly status: number | undefined;

  constructor(
    url: string,
    reason: string,
    hint: string,
    more: { readonly status?: number | undefined; readonly closeCode?: number; readonly cause?: unknown } = {},
  ) {
    const options = more.cause === undefined ? undefined : { cause: more.cause };
    super(`could not connect to ${url}: ${reason} (hint: ${hint})`, more.closeCode ?? 1006, "", options);
    this.url = url;
    this.reason = reason;
    this.hint = hint;
    this.status = more.status;
  }
}

/**
 * The token function (`connect`'s `token` when it is a function) threw or rejected:
 * the backend's token endpoint may be briefly down. `cause` is what it threw. Retried:
 * a rejoin calls the function again, up to `reconnect.maxAttempts`, after which the
 * event stream throws this error; the first `join` rejects with it (not retried). A
 * function that returns no token is a {@link ConfigInvalidError}, never retried. Not
 * a wire code.
 */
export class TokenProviderError extends PosecastError {
  constructor(message: string, options?: { readonly cause?: unknown }) {
    super("TOKEN_PROVIDER_FAILED", message, options);
  }
}

export interface ProtocolErrorOptions {
  /** Path of the offending field, e.g. `trackers[2]` or `limits.max_players`. */
  field?: string | undefined;
  /** `seq` of the frame that caused it. */
  refSeq?: number | undefined;
  /** Whether the connection ends; defaults to the code's usual value. */
  fatal?: boolean | undefined;
}

/** A wire error code: raised by the decoder, or received in an `error` message. */
export class ProtocolError extends PosecastError {
  /** The code this class stands for (the base class stands for codes it does not know). */
  static readonly code: string = "INTERNAL";
  /** Whether this code ends the connection by default (`proto/errors.json`). */
  static readonly fatal: boolean = false;

  readonly field: string | undefined;
  readonly refSeq: number | undefined;
  readonly fatal: boolean;

  constructor(message: string, options: ProtocolErrorOptions = {}, code?: string) {
    const cls = new.target as unknown as typeof ProtocolError;
    super(code ?? cls.code, message);
    this.field = options.field;
    this.refSeq = options.refSeq;
    this.fatal = options.fatal ?? cls.fatal;
  }

  /** The class for a wire code; {@link ProtocolError} itself for an unknown code. */
  static forCode(code: string): typeof ProtocolError {
    return BY_CODE.get(code) ?? ProtocolError;
  }
}

export class MalformedError extends ProtocolError {
  static override readonly code = "MALFORMED";
  static override readonly fatal = true;
}
export class TooLargeError extends ProtocolError {
  static override readonly code = "TOO_LARGE";
  static override readonly fatal = true;
}
export class UnknownTypeError extends ProtocolError {
  static override readonly code = "UNKNOWN_TYPE";
}
export class BadFieldError extends ProtocolError {
  static override readonly code = "BAD_FIELD";
}
export class OutOfRangeError extends ProtocolError {
  static override readonly code = "OUT_OF_RANGE";
}
export class NotNormalisedError extends ProtocolError {
  static override readonly code = "NOT_NORMALISED";
}
export class OutOfOrderError extends ProtocolError {
  static override readonly code = "OUT_OF_ORDER";
}
export class DuplicateError extends ProtocolError {
  static override readonly code = "DUPLICATE";
}
export class RateLimitedError extends ProtocolError {
  static override readonly code = "RATE_LIMITED";
}
export class UnauthenticatedError extends ProtocolError {
  static override readonly code = "UNAUTHENTICATED";
  static override readonly fatal = true;
}
export class TokenExpiredError extends ProtocolError {
  static override readonly code = "TOKEN_EXPIRED";
  static override readonly fatal = true;
}
export class ForbiddenError extends ProtocolError {
  static override readonly code = "FORBIDDEN";
}
export class VersionUnsupportedError extends ProtocolError {
  static override readonly code = "VERSION_UNSUPPORTED";
  static override readonly fatal = true;
}
export class LayoutUnsupportedError extends ProtocolError {
  static override readonly code = "LAYOUT_UNSUPPORTED";
  static override readonly fatal = true;
}
export class RoomFullError extends ProtocolError {
  static override readonly code = "ROOM_FULL";
  static override readonly fatal = true;
}
export class NotJoinedError extends ProtocolError {
  static override readonly code = "NOT_JOINED";
  static override readonly fatal = true;
}
export class AlreadyJoinedError extends ProtocolError {
  static override readonly code = "ALREADY_JOINED";
}
export class NotFoundError extends ProtocolError {
  static override readonly code = "NOT_FOUND";
}
export class CalibrationFailedError extends ProtocolError {
  static override readonly code = "CALIBRATION_FAILED";
}
export class TimedOutError extends ProtocolError {
  static override readonly code = "TIMED_OUT";
  static override readonly fatal = true;
}
export class KickedError extends ProtocolError {
  static override readonly code = "KICKED";
  static override readonly fatal = true;
}
export class ReplacedError extends ProtocolError {
  static override readonly code = "REPLACED";
  static override readonly fatal = true;
}
export class SlowConsumerError extends ProtocolError {
  static override readonly code = "SLOW_CONSUMER";
  static override readonly fatal = true;
}
export class ServerShutdownError extends ProtocolError {
  static override readonly code = "SERVER_SHUTDOWN";
  static override readonly fatal = true;
}
export class InternalError extends ProtocolError {
  static override readonly code = "INTERNAL";
}

/** Every wire error class, in the order of `proto/errors.json`. */
export const PROTOCOL_ERRORS: readonly (typeof ProtocolError)[] = [
  MalformedError,
  TooLargeError,
  UnknownTypeError,
  BadFieldError,
  OutOfRangeError,
  NotNormalisedError,
  OutOfOrderError,
  DuplicateError,
  RateLimitedError,
  UnauthenticatedError,
  TokenExpiredError,
  ForbiddenError,
  VersionUnsupportedError,
  LayoutUnsupportedError,
  RoomFullError,
  NotJoinedError,
  AlreadyJoinedError,
  NotFoundError,
  CalibrationFailedError,
  TimedOutError,
  KickedError,
  ReplacedError,
  SlowConsumerError,
  ServerShutdownError,
  InternalError,
];

/** The codes a decoder itself produces (`decoder: true` in `proto/errors.json`). */
export const DECODER_CODES: ReadonlySet<string> = new Set([
  "MALFORMED",
  "TOO_LARGE",
  "UNKNOWN_TYPE",
  "BAD_FIELD",
  "OUT_OF_RANGE",
  "NOT_NORMALISED",
  "VERSION_UNSUPPORTED",
]);

const BY_CODE: ReadonlyMap<string, typeof ProtocolError> = new Map(
  PROTOCOL_ERRORS.map((cls) => [cls.code, cls]),
);

/** The fields of a wire `error` message that {@link errorFromMessage} needs. */
export interface ErrorFields {
  readonly code: string;
  readonly message: string;
  readonly fatal: boolean;
  readonly field?: string | undefined;
  readonly ref_seq?: number | undefined;
}

/**
 * The typed error for a received `error` message. The message's `fatal` wins over
 * the code's default; an unknown code (a newer server) gives a plain
 * {@link ProtocolError} that keeps the code.
 */
export function errorFromMessage(msg: ErrorFields): ProtocolError {
  const cls = ProtocolError.forCode(msg.code);
  return new cls(
    msg.message || msg.code,
    { field: msg.field, refSeq: msg.ref_seq, fatal: msg.fatal },
    msg.code,
  );
}

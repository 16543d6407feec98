/**
 * When and how soon the client reconnects (pure: no timers, no sockets). The client's
 * reconnect loop asks {@link isRetryable} whether a lost connection or a failed rejoin
 * can be cured by trying again, and waits {@link backoffDelayS} before each attempt:
 * exponential back-off with full jitter, capped.
 */

import { PosecastError } from "./errors.js";

export interface ReconnectOptions {
  /** Back-off before the first retry, seconds (before jitter). Default 0.25. */
  readonly initialDelayS?: number;
  /** Longest back-off, seconds. Default 10. */
  readonly maxDelayS?: number;
  /** Back-off growth per failed attempt. Default 2. */
  readonly factor?: number;
  /** Consecutive failed attempts before giving up. Default Infinity. */
  readonly maxAttempts?: number;
}

/** The reconnect options in force, every default filled in. */
export type ReconnectPolicy = Required<ReconnectOptions>;

/** Codes a reconnect can cure: the server went away or gave up on this connection. */
const RETRYABLE_CODES: ReadonlySet<string> = new Set([
  "CONNECTION_CLOSED",
  "TOKEN_PROVIDER_FAILED", // the token function threw: its backend may be back soon
  "SERVER_SHUTDOWN",
  "TIMED_OUT",
  "SLOW_CONSUMER",
  "INTERNAL",
]);

/** `ConnectOptions.reconnect` as a policy (absent or `true`: the defaults), or `undefined` for `false`. */
export function reconnectPolicy(option: boolean | ReconnectOptions | undefined): ReconnectPolicy | undefined {
  const r = option ?? true;
  return r === false
    ? undefined
    : {
        initialDelayS: 0.25,
        maxDelayS: 10,
        factor: 2,
        maxAttempts: Infinity,
        ...(r === true ? {} : r),
      };
}

/**
 * Seconds to wait before reconnect attempt `attempt` (1, 2, ...): full jitter, `random()`
 * (in [0, 1)) times the capped exponential back-off.
 */
export function backoffDelayS(policy: ReconnectPolicy, attempt: number, random: () => number): number {
  const cap = Math.min(policy.maxDelayS, policy.initialDelayS * policy.factor ** (attempt - 1));
  return cap * random(); // full jitter
}

/**
 * Whether trying again can cure `err`: a {@link PosecastError} with a retryable code, or
 * TOKEN_EXPIRED where the token comes from a function (which is asked again).
 */
export function isRetryable(err: unknown, tokenIsFunction: boolean): boolean {
  if (!(err instanceof PosecastError)) return false;
  if (err.code === "TOKEN_EXPIRED") return tokenIsFunction;
  return RETRYABLE_CODES.has(err.code);
}

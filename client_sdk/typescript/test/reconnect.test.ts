/**
 * reconnect.ts alone: the policy's defaults, the back-off (growth, cap, full jitter), and
 * which errors a reconnect can cure. The reconnect loop itself runs in client.test.ts.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import {
  ConnectionClosedError,
  ForbiddenError,
  KickedError,
  PosecastError,
  ServerShutdownError,
  TokenProviderError,
  UnauthenticatedError,
  errorFromMessage,
} from "../src/errors.js";
import { backoffDelayS, isRetryable, reconnectPolicy } from "../src/reconnect.js";

test("the policy: defaults when absent or true, none when false, given fields win", () => {
  const defaults = { initialDelayS: 0.25, maxDelayS: 10, factor: 2, maxAttempts: Infinity };
  assert.deepEqual(reconnectPolicy(undefined), defaults);
  assert.deepEqual(reconnectPolicy(true), defaults);
  assert.equal(reconnectPolicy(false), undefined);
  assert.deepEqual(reconnectPolicy({ maxDelayS: 5, maxAttempts: 3 }), { ...defaults, maxDelayS: 5, maxAttempts: 3 });
});

test("back-off grows by the factor up to the cap, times the jitter", () => {
  const policy = reconnectPolicy({ initialDelayS: 0.5, maxDelayS: 3, factor: 2 })!;
  const top = (attempt: number): number => backoffDelayS(policy, attempt, () => 1);
  assert.deepEqual([1, 2, 3, 4, 5, 50].map(top), [0.5, 1, 2, 3, 3, 3]);
  assert.equal(backoffDelayS(policy, 3, () => 0), 0); // full jitter: anywhere from 0
  assert.equal(backoffDelayS(policy, 3, () => 0.25), 0.5);
});

test("retryable: the server went away or gave up; not a refusal, nor a non-posecast error", () => {
  const code = (c: string): PosecastError => errorFromMessage({ code: c, message: "m", fatal: true });
  for (const err of [
    new ConnectionClosedError("lost"),
    new ServerShutdownError("bye", { fatal: true }),
    new TokenProviderError("threw"),
    code("TIMED_OUT"),
    code("SLOW_CONSUMER"),
    code("INTERNAL"),
  ]) {
    assert.ok(isRetryable(err, false), err.code);
  }
  for (const err of [new KickedError("out"), new UnauthenticatedError("no"), new ForbiddenError("no"), code("ROOM_FULL")]) {
    assert.ok(!isRetryable(err, true), err.code);
  }
  assert.ok(!isRetryable(new Error("a bug"), true));
  assert.ok(!isRetryable(undefined, true));
  // An expired token is cured only by asking the token function for a fresh one.
  assert.ok(isRetryable(code("TOKEN_EXPIRED"), true));
  assert.ok(!isRetryable(code("TOKEN_EXPIRED"), false));
});

/**
 * decoders.ts and encoders.ts directly (the codec's vectors, through `decode` and
 * `encode`, are in vectors.test.ts): every decoder names the field it misses, and the
 * encoders write `type` first, leave absent optionals out and write floats as float64
 * even when they are whole numbers.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import { DECODERS } from "../src/decoders.js";
import { toWire } from "../src/encoders.js";
import { ProtocolError } from "../src/errors.js";
import { DEFAULT_LIMITS, type Message } from "../src/messages.js";
import { Float64, type Wire } from "../src/msgpack.js";

test("each decoder, given a bare type, throws a ProtocolError naming the field it misses", () => {
  const noFields = new Set(["resync", "bye"]); // nothing required
  for (const [kind, decoder] of Object.entries(DECODERS)) {
    for (const version of [1, 2]) {
      const bare = new Map<string, Wire>([["type", kind]]);
      if (noFields.has(kind)) {
        assert.equal(decoder(bare, DEFAULT_LIMITS, version).type, kind);
        continue;
      }
      assert.throws(
        () => decoder(bare, DEFAULT_LIMITS, version),
        (err: unknown) => err instanceof ProtocolError && typeof err.field === "string" && err.field !== "",
        `${kind} v${version}`,
      );
    }
  }
});

test("encoders: type first, absent optionals left out, whole floats still float64", () => {
  const cases: [Message, string[]][] = [
    [{ type: "hello", version: 2, token: "t", room: "r", name: "n", rate_hz: 60 }, ["type", "version", "token", "room", "name", "rate_hz"]],
    [{ type: "hello", version: 1, token: "t", room: "r", name: "n", watch: [] }, ["type", "version", "token", "room", "name"]],
    [{ type: "ping", t0: 3 }, ["type", "t0"]],
    [{ type: "pose_rate", rate_hz: 30 }, ["type", "rate_hz"]],
    [{ type: "error", code: "X", message: "m", fatal: false }, ["type", "code", "message", "fatal"]],
    [{ type: "resync" }, ["type"]],
  ];
  for (const [msg, keys] of cases) {
    const wire = toWire(msg);
    assert.deepEqual([...wire.keys()], keys, msg.type);
    assert.equal(wire.get("type"), msg.type);
  }
  assert.ok(toWire({ type: "ping", t0: 3 }).get("t0") instanceof Float64);
  assert.ok(toWire({ type: "pose_rate", rate_hz: 30 }).get("rate_hz") instanceof Float64);
  assert.equal(toWire({ type: "hello", version: 2, token: "t", room: "r", name: "n" }).get("version"), 2); // an int
});

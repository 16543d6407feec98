/** The error classes match proto/errors.json, and wire errors map onto them. */

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { test } from "node:test";

import {
  BadFieldError,
  DECODER_CODES,
  errorFromMessage,
  KickedError,
  PosecastError,
  PROTOCOL_ERRORS,
  ProtocolError,
  RateLimitedError,
  UnauthenticatedError,
} from "../src/errors.js";
import { repoRoot } from "./helpers.js";

interface Row {
  code: string;
  fatal: boolean;
  decoder: boolean;
}
const TABLE = JSON.parse(readFileSync(join(repoRoot(), "proto", "errors.json"), "utf8")) as Row[];

test("one class per code of proto/errors.json, in its order, with its fatal default", () => {
  assert.deepEqual(
    PROTOCOL_ERRORS.map((cls) => [cls.code, cls.fatal]),
    TABLE.map((row) => [row.code, row.fatal]),
  );
  assert.deepEqual([...DECODER_CODES].sort(), TABLE.filter((r) => r.decoder).map((r) => r.code).sort());
});

test("class names are the code in CamelCase plus Error", () => {
  for (const cls of PROTOCOL_ERRORS) {
    const camel = cls.code
      .toLowerCase()
      .split("_")
      .map((w) => w[0]!.toUpperCase() + w.slice(1))
      .join("");
    assert.equal(cls.name, camel + "Error");
    const err = new cls("x");
    assert.ok(err instanceof ProtocolError && err instanceof PosecastError && err instanceof Error);
    assert.equal(err.code, cls.code);
    assert.equal(err.name, cls.name);
  }
});

test("a wire error becomes its class; the message's fatal wins; fields carry over", () => {
  const e = errorFromMessage({ code: "KICKED", message: "bye now", fatal: true });
  assert.ok(e instanceof KickedError);
  assert.equal(e.message, "bye now");
  const f = errorFromMessage({
    code: "BAD_FIELD", message: "", fatal: false, field: "trackers[2]", ref_seq: 7,
  });
  assert.ok(f instanceof BadFieldError);
  assert.deepEqual([f.field, f.refSeq, f.fatal, f.message], ["trackers[2]", 7, false, "BAD_FIELD"]);
  assert.equal(errorFromMessage({ code: "RATE_LIMITED", message: "", fatal: true }).fatal, true);
  assert.ok(new RateLimitedError("x").fatal === false);
  assert.ok(new UnauthenticatedError("x").fatal);
});

test("an unknown code (a newer server) keeps its code on the base class", () => {
  const e = errorFromMessage({ code: "QUOTA_EXCEEDED", message: "later", fatal: false });
  assert.equal(e.constructor, ProtocolError);
  assert.equal(e.code, "QUOTA_EXCEEDED");
});

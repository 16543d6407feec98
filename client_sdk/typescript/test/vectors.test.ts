/**
 * proto/vectors/*.json against the TypeScript codec (proto/README.md, "Test vectors"):
 *
 * 1. decode(canonical_hex) succeeds and encode() gives canonical_hex back, byte for byte;
 * 2. the decoded message, as a wire map, equals `message` (key order included);
 * 3. every also_accept_hex decodes and re-encodes to canonical_hex;
 * 4. every invalid hex fails with exactly `error`, and with `field` where one is given.
 */

import assert from "node:assert/strict";
import { readdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { describe, test } from "node:test";

import { decode, encode, MESSAGE_TYPES, toWire } from "../src/codec.js";
import { DECODER_CODES, ProtocolError } from "../src/errors.js";
import { fromHex, keyOrder, repoRoot, toHex, wireToJson } from "./helpers.js";

interface ValidCase {
  name: string;
  description: string;
  versions: number[];
  message: Record<string, unknown>;
  canonical_hex: string;
  also_accept_hex: string[];
}
interface InvalidCase {
  name: string;
  description: string;
  versions: number[];
  hex: string;
  error: string;
  field?: string;
}
type Case = ValidCase | InvalidCase;

const VECTORS = join(repoRoot(), "proto", "vectors");
const FILES = readdirSync(VECTORS).filter((f) => f.endsWith(".json")).sort();
// This codec speaks v1: it runs every case that holds in v1 (`versions` includes 1). The
// v2 cases (poses streams among them) wait for the TypeScript v2 codec.
const CASES: [string, Case][] = FILES.flatMap((file) =>
  (JSON.parse(readFileSync(join(VECTORS, file), "utf8")) as Case[])
    .filter((c) => c.versions.includes(1))
    .map((c) => [file.replace(/\.json$/, ""), c] as [string, Case]),
);

function decodeError(hex: string): ProtocolError {
  try {
    decode(fromHex(hex));
  } catch (err) {
    if (err instanceof ProtocolError) return err;
    throw err;
  }
  assert.fail("decoded without an error");
}

for (const file of [...new Set(CASES.map(([f]) => f))]) {
  describe(`vectors/${file}`, () => {
    for (const [, c] of CASES.filter(([f]) => f === file)) {
      if ("message" in c) {
        test(c.name, () => {
          const msg = decode(fromHex(c.canonical_hex));
          assert.equal(toHex(encode(msg)), c.canonical_hex);
          const wire = wireToJson(toWire(msg));
          assert.deepEqual(wire, c.message);
          assert.deepEqual(keyOrder(wire), keyOrder(c.message));
          for (const alt of c.also_accept_hex) {
            assert.equal(toHex(encode(decode(fromHex(alt)))), c.canonical_hex, alt.slice(0, 80));
          }
        });
      } else {
        test(`${c.name} -> ${c.error}`, () => {
          const err = decodeError(c.hex);
          assert.equal(err.code, c.error, err.message);
          assert.equal(err.field, c.field);
          assert.ok(err instanceof ProtocolError.forCode(c.error));
        });
      }
    }
  });
}

test("the vectors cover every message type and every decoder code", () => {
  const types = new Set(CASES.flatMap(([, c]) => ("message" in c ? [c.message["type"]] : [])));
  assert.deepEqual([...types].sort(), [...MESSAGE_TYPES].sort());
  assert.ok(CASES.some(([f]) => f === "envelope"));
  const errors = new Set(CASES.flatMap(([, c]) => ("error" in c ? [c.error] : [])));
  assert.deepEqual([...errors].sort(), [...DECODER_CODES].sort());
  assert.ok(CASES.length > 150, `only ${CASES.length} cases`);
});

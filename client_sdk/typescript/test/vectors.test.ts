/**
 * proto/vectors/*.json against the TypeScript codec (proto/README.md, "Test vectors"),
 * every case in every protocol version it lists (`versions`):
 *
 * 1. decode(canonical_hex) succeeds and encode() gives canonical_hex back, byte for byte;
 * 2. the decoded message, as a wire map, equals `message` (key order included);
 * 3. every also_accept_hex decodes and re-encodes to canonical_hex;
 * 4. every invalid hex fails with exactly `error`, and with `field` where one is given;
 * 5. (v2) every stream case of poses.json decodes, record by record, to its `expect`
 *    within `tolerance`, or fails on its last message where it says.
 */

import assert from "node:assert/strict";
import { readdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { describe, test } from "node:test";

import { ALL_MESSAGE_TYPES, decode, encode, MESSAGE_TYPES, MESSAGE_TYPES_V2, toWire } from "../src/codec.js";
import { DECODER_CODES, ProtocolError } from "../src/errors.js";
import { NUM_JOINTS } from "../src/messages.js";
import { type AvatarState, decodeRecords, fk, items2world, rootMetres, skeleton2offsets } from "../src/records.js";
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
interface ExpectedRecord {
  // The vector file's keys, as in proto/vectors: `handle` is the avatar id.
  handle: number;
  seq: number;
  keyframe: boolean;
  reach_limited: boolean;
  root: number[];
  items: number[][];
  positions: number[][];
}
interface StreamCase {
  name: string;
  description: string;
  versions: number[];
  avatars: { handle: number; player: string; skeleton: { $bin: string } }[];
  messages: string[];
  expect: ExpectedRecord[][];
  tolerance: number;
  error?: string;
  field?: string;
}
type Case = ValidCase | InvalidCase | StreamCase;

const VECTORS = join(repoRoot(), "proto", "vectors");
const FILES = readdirSync(VECTORS).filter((f) => f.endsWith(".json")).sort();
const CASES: [string, Case][] = FILES.flatMap((file) =>
  (JSON.parse(readFileSync(join(VECTORS, file), "utf8")) as Case[]).map(
    (c) => [file.replace(/\.json$/, ""), c] as [string, Case],
  ),
);

function decodeError(hex: string, version: number): ProtocolError {
  try {
    decode(fromHex(hex), { version });
  } catch (err) {
    if (err instanceof ProtocolError) return err;
    throw err;
  }
  assert.fail("decoded without an error");
}

function assertClose(actual: ArrayLike<number>, expected: readonly number[], tol: number, what: string): void {
  assert.equal(actual.length, expected.length, what);
  for (let i = 0; i < expected.length; i++) {
    const d = Math.abs(actual[i]! - expected[i]!);
    assert.ok(d <= tol, `${what}[${i}]: ${actual[i]} vs ${expected[i]} (off ${d})`);
  }
}

function runStream(c: StreamCase): void {
  const avatars = new Map<number, AvatarState | null>();
  const offsets = new Map<number, Float64Array>();
  for (const a of c.avatars) {
    avatars.set(a.handle, null);
    offsets.set(a.handle, skeleton2offsets(fromHex(a.skeleton.$bin)));
  }
  c.messages.forEach((hex, k) => {
    const msg = decode(fromHex(hex), { version: 2 });
    assert.equal(msg.type, "poses");
    if (msg.type !== "poses") return;
    if (c.error !== undefined && k === c.messages.length - 1) {
      let thrown: unknown;
      try {
        decodeRecords(msg.data, avatars);
      } catch (err) {
        thrown = err;
      }
      assert.ok(thrown instanceof ProtocolError, `message ${k} decoded without an error`);
      assert.equal(thrown.code, c.error, thrown.message);
      assert.equal(thrown.field, c.field);
      return;
    }
    const records = decodeRecords(msg.data, avatars);
    const expected = c.expect[k]!;
    assert.equal(records.length, expected.length, `message ${k}: records`);
    records.forEach((rec, i) => {
      const e = expected[i]!;
      const at = `message ${k} record ${i}`;
      assert.deepEqual(
        [rec.avatarId, rec.state.seq, rec.keyframe, rec.reachLimited],
        [e.handle, e.seq, e.keyframe, e.reach_limited],
        at,
      );
      assertClose(rootMetres(rec.state), e.root, c.tolerance, `${at} root`);
      assertClose(rec.state.items, e.items.flat(), c.tolerance, `${at} items`);
      const world = items2world(rec.state.items);
      const positions = fk(world, rootMetres(rec.state), offsets.get(rec.avatarId)!);
      assertClose(positions, e.positions.flat(), c.tolerance, `${at} positions`);
    });
  });
}

for (const file of [...new Set(CASES.map(([f]) => f))]) {
  describe(`vectors/${file}`, () => {
    for (const [, c] of CASES.filter(([f]) => f === file)) {
      for (const version of c.versions) {
        const v = `v${version}`;
        if ("messages" in c) {
          test(`${c.name} (${v} stream)${c.error === undefined ? "" : ` -> ${c.error}`}`, () => runStream(c));
        } else if ("message" in c) {
          test(`${c.name} (${v})`, () => {
            const msg = decode(fromHex(c.canonical_hex), { version });
            assert.equal(toHex(encode(msg)), c.canonical_hex);
            const wire = wireToJson(toWire(msg));
            assert.deepEqual(wire, c.message);
            assert.deepEqual(keyOrder(wire), keyOrder(c.message));
            for (const alt of c.also_accept_hex) {
              const again = encode(decode(fromHex(alt), { version }));
              assert.equal(toHex(again), c.canonical_hex, alt.slice(0, 80));
            }
          });
        } else {
          test(`${c.name} (${v}) -> ${c.error}`, () => {
            const err = decodeError(c.hex, version);
            assert.equal(err.code, c.error, err.message);
            assert.equal(err.field, c.field);
            assert.ok(err instanceof ProtocolError.forCode(c.error));
          });
        }
      }
    }
  });
}

test("the vectors cover every message type of each version and every decoder code", () => {
  for (const [version, types] of [
    [1, MESSAGE_TYPES],
    [2, MESSAGE_TYPES_V2],
  ] as const) {
    const seen = new Set(
      CASES.flatMap(([, c]) => ("message" in c && c.versions.includes(version) ? [c.message["type"]] : [])),
    );
    assert.deepEqual([...seen].sort(), [...types].sort(), `v${version}`);
  }
  assert.deepEqual([...new Set([...MESSAGE_TYPES, ...MESSAGE_TYPES_V2])].sort(), [...ALL_MESSAGE_TYPES].sort());
  assert.ok(CASES.some(([f]) => f === "envelope"));
  const errors = new Set(CASES.flatMap(([, c]) => ("error" in c && c.error !== undefined ? [c.error] : [])));
  assert.deepEqual([...errors].sort(), [...DECODER_CODES].sort());
  const streams = CASES.filter(([, c]) => "messages" in c);
  assert.ok(streams.length >= 10, `only ${streams.length} stream cases`);
  assert.ok(CASES.length > 200, `only ${CASES.length} cases`);
});

test("a stream's FK positions come from the items (an independent check of fk)", () => {
  // The rest pose (every item identity) puts each joint at the sum of its bone offsets.
  const items = new Float64Array(NUM_JOINTS * 4);
  for (let j = 0; j < NUM_JOINTS; j++) items[4 * j + 3] = 1;
  const offsets = new Float64Array(NUM_JOINTS * 3);
  for (let i = 3; i < offsets.length; i++) offsets[i] = (i % 7) * 0.01;
  const pos = fk(items2world(items), [1, 2, 3], offsets);
  // HEAD (4) sits on NECK (3), CHEST (2), SPINE (1), PELVIS.
  for (let c = 0; c < 3; c++) {
    const want = [1, 2, 3][c]! + offsets[3 + c]! + offsets[6 + c]! + offsets[9 + c]! + offsets[12 + c]!;
    assert.ok(Math.abs(pos[12 + c]! - want) < 1e-12);
  }
});

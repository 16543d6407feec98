/**
 * proto/schema.json against every message in proto/vectors, with ajv (Python's
 * `jsonschema` does the same in tests/proto/test_schema.py): two validators, one schema.
 *
 * - schema.json is a valid draft 2020-12 schema (ajv's meta-schema check);
 * - every valid case, its canonical bytes and every also_accept_hex rendered by the JSON
 *   data model (./datamodel.ts), passes in every version it lists, and its canonical
 *   rendering is the case's `message`; so does every message of a stream;
 * - every invalid case fails in every version it lists, except those
 *   proto/schema_gaps.json names: those pass, or (`no_rendering`) have no rendering.
 *
 * And proto/skeleton.json, the spec's body tables, is this SDK's: joints, parents,
 * tracker slots, sites.
 */

import assert from "node:assert/strict";
import { readdirSync, readFileSync } from "node:fs";
import { join } from "node:path";
import { describe, test } from "node:test";

import { Ajv2020, type ValidateFunction } from "ajv/dist/2020.js";

import { JOINT_NAMES, PARENTS, TRACKER_SLOTS } from "../src/messages.js";
import { SITE_JOINTS, SITES } from "../src/sites.js";
import { NotRepresentableError, render } from "./datamodel.js";
import { fromHex, repoRoot } from "./helpers.js";

interface Case {
  name: string;
  versions: number[];
  message?: unknown;
  canonical_hex?: string;
  also_accept_hex?: string[];
  messages?: string[];
  hex?: string;
  error?: string;
}

const PROTO = join(repoRoot(), "proto");
const read = (path: string): unknown => JSON.parse(readFileSync(path, "utf8"));
const SCHEMA = read(join(PROTO, "schema.json")) as { $id: string; $schema: string };
const GAPS = read(join(PROTO, "schema_gaps.json")) as {
  reasons: Record<string, string>;
  vectors: Record<string, { reason: string; versions: number[] }>;
};
const CASES: Case[] = readdirSync(join(PROTO, "vectors"))
  .filter((f) => f.endsWith(".json"))
  .sort()
  .flatMap((f) => read(join(PROTO, "vectors", f)) as Case[]);

// strictTypes and strictTuples are ajv's lint for hand-written schemas: schema.json puts
// bounds in if/then branches whose type the enclosing schema already fixes. strictSchema
// stays on: a keyword no draft defines is an error.
const ajv = new Ajv2020({ strict: true, strictTypes: false, strictTuples: false, allErrors: false });
ajv.addSchema(SCHEMA);
const VALIDATORS: Record<number, ValidateFunction> = Object.fromEntries(
  [1, 2].map((v) => {
    const fn = ajv.getSchema(`${SCHEMA.$id}#/$defs/v${v}`);
    assert.ok(fn, `no #/$defs/v${v}`);
    return [v, fn];
  }),
);

function errors(version: number, message: unknown): string {
  const fn = VALIDATORS[version]!;
  return fn(message) ? "" : ajv.errorsText(fn.errors);
}

describe("schema.json (ajv, draft 2020-12)", () => {
  test("is a valid draft 2020-12 schema", () => {
    assert.equal(SCHEMA.$schema, "https://json-schema.org/draft/2020-12/schema");
    assert.equal(ajv.validateSchema(SCHEMA), true, ajv.errorsText(ajv.errors));
  });

  test("every valid vector passes, every encoding, every version", () => {
    let n = 0;
    for (const c of CASES.filter((c) => c.message !== undefined)) {
      assert.deepEqual(render(fromHex(c.canonical_hex!)), c.message, c.name);
      for (const v of c.versions) {
        for (const hex of [c.canonical_hex!, ...c.also_accept_hex!]) {
          assert.equal(errors(v, render(fromHex(hex))), "", `${c.name} v${v} ${hex.slice(0, 32)}`);
          n++;
        }
      }
    }
    assert.ok(n > 500, `${n} encodings`);
  });

  test("every message of a pose-record stream is a valid poses", () => {
    for (const c of CASES.filter((c) => c.messages !== undefined)) {
      for (const v of c.versions) {
        for (const hex of c.messages!) assert.equal(errors(v, render(fromHex(hex))), "", c.name);
      }
    }
  });

  test("every invalid vector fails, but for those schema_gaps.json names", () => {
    let failed = 0;
    for (const c of CASES.filter((c) => c.hex !== undefined)) {
      const gap = GAPS.vectors[c.name];
      const reason = (v: number): string | undefined => (gap?.versions.includes(v) ? gap.reason : undefined);
      let message: unknown;
      try {
        message = render(fromHex(c.hex!));
      } catch (err) {
        assert.ok(err instanceof NotRepresentableError, String(err));
        for (const v of c.versions) assert.equal(reason(v), "no_rendering", `${c.name}: no rendering (${err.message})`);
        continue;
      }
      for (const v of c.versions) {
        const why = errors(v, message);
        if (reason(v) === undefined) {
          assert.notEqual(why, "", `${c.name} (${c.error}) passes the schema in v${v}`);
          failed++;
        } else {
          assert.notEqual(reason(v), "no_rendering", `${c.name} has a rendering`);
          assert.equal(why, "", `${c.name} is listed for v${v} in schema_gaps.json but fails`);
        }
      }
    }
    assert.ok(failed > 200, `${failed} refusals`);
    const reasons = new Set(Object.values(GAPS.vectors).map((g) => g.reason));
    assert.deepEqual([...reasons].sort(), Object.keys(GAPS.reasons).sort());
  });
});

describe("skeleton.json is this SDK's", () => {
  const body = read(join(PROTO, "skeleton.json")) as {
    joints: { name: string; parent_index: number }[];
    tracker_slots: { name: string; joint: string }[];
    sites: { name: string; joint: string }[];
  };
  test("joints and parents", () => {
    assert.deepEqual(body.joints.map((j) => j.name), [...JOINT_NAMES]);
    assert.deepEqual(body.joints.map((j) => j.parent_index), [...PARENTS]);
  });
  test("tracker slots and sites", () => {
    assert.deepEqual(body.tracker_slots.map((s) => s.name), [...TRACKER_SLOTS]);
    assert.deepEqual(body.sites.map((s) => s.name), [...SITES]);
    assert.deepEqual(body.sites.map((s) => s.joint), SITES.map((s) => SITE_JOINTS[s]));
  });
});

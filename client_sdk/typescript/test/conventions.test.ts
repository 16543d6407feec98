/**
 * Engine conventions: the shared table proto/vectors/sdk/conventions.json (the Python
 * SDK runs the same one), the inverses, and the bone-name table.
 */

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { describe, test } from "node:test";

import {
  BONE_RIGS,
  BONES,
  boneName,
  ENGINE_FRAMES,
  ENGINES,
  engineToPos,
  engineToQuat,
  headToXRView,
  poseToEngine,
  type Engine,
} from "../src/conventions.js";
import { JOINT_NAMES } from "../src/messages.js";
import { repoRoot } from "./helpers.js";

interface Case {
  name: string;
  engine: Engine;
  positions: number[][];
  rotations: number[][];
  expect_positions: number[][];
  expect_rotations: number[][];
}
const TABLE = JSON.parse(
  readFileSync(join(repoRoot(), "proto", "vectors", "sdk", "conventions.json"), "utf8"),
) as {
  tolerance: { position: number; rotation: number };
  engines: Record<string, { basis: number[][]; scale: number; right_handed: boolean }>;
  cases: Case[];
  head2xrview: { head: number[]; view: number[] }[];
  bones: Record<string, string>[];
};

function maxDiff(a: ArrayLike<number>, b: readonly number[]): number {
  assert.equal(a.length, b.length);
  let m = 0;
  for (let i = 0; i < b.length; i++) m = Math.max(m, Math.abs(a[i]! - b[i]!));
  return m;
}

function rotDiff(a: ArrayLike<number>, b: readonly number[]): number {
  let m = 0;
  for (let j = 0; j < b.length; j += 4) {
    let plus = 0;
    let minus = 0;
    for (let k = 0; k < 4; k++) {
      plus = Math.max(plus, Math.abs(a[j + k]! - b[j + k]!));
      minus = Math.max(minus, Math.abs(a[j + k]! + b[j + k]!));
    }
    m = Math.max(m, Math.min(plus, minus));
  }
  return m;
}

describe("proto/vectors/sdk/conventions.json", () => {
  for (const c of TABLE.cases) {
    test(c.name, () => {
      const out = poseToEngine({ positions: c.positions.flat(), rotations: c.rotations.flat() }, c.engine);
      assert.ok(maxDiff(out.positions, c.expect_positions.flat()) <= TABLE.tolerance.position);
      assert.ok(out.rotations);
      assert.ok(rotDiff(out.rotations, c.expect_rotations.flat()) <= TABLE.tolerance.rotation);
      assert.ok(maxDiff(engineToPos(c.expect_positions.flat(), c.engine), c.positions.flat()) <= 1e-9);
      assert.ok(rotDiff(engineToQuat(c.expect_rotations.flat(), c.engine), c.rotations.flat()) <= 1e-9);
    });
  }

  test("frames", () => {
    assert.deepEqual(Object.keys(TABLE.engines).sort(), [...ENGINES].sort());
    for (const e of ENGINES) {
      const f = ENGINE_FRAMES[e];
      const want = TABLE.engines[e]!;
      assert.ok(maxDiff(f.basis, want.basis.flat()) <= 1e-12, e);
      assert.deepEqual([f.scale, f.rightHanded], [want.scale, want.right_handed], e);
    }
  });

  test("head to WebXR view", () => {
    for (const row of TABLE.head2xrview) {
      assert.ok(rotDiff(headToXRView(row.head), row.view) <= TABLE.tolerance.rotation);
    }
  });

  test("bone names", () => {
    assert.deepEqual(TABLE.bones.map((r) => r["joint"]), [...JOINT_NAMES]);
    for (const rig of BONE_RIGS) {
      assert.deepEqual([...BONES[rig]], TABLE.bones.map((r) => r[rig]), rig);
      assert.equal(new Set(BONES[rig]).size, 19, `${rig}: a bone used twice`);
    }
    assert.equal(boneName("LEFT_FOREARM", "unity"), "LeftLowerArm");
  });
});

test("a positions-only pose converts without rotations", () => {
  const out = poseToEngine({ positions: new Float64Array(57) }, "unreal");
  assert.equal(out.rotations, undefined);
  assert.equal(out.positions.length, 57);
});

test("an unknown engine is refused", () => {
  assert.throws(() => poseToEngine({ positions: [0, 0, 1] }, "godot" as Engine), RangeError);
});

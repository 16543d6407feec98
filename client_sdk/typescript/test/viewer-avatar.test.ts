/**
 * The viewer's skinned avatar on the CPU (three.js's own skinning formula, no WebGL):
 * poses built by FK from random rotations at another body scale put every checked ring
 * of the mesh on its joints; a bone rotation that disagrees with the positions tears
 * the limb off (so the check can fail); a twist about a bone's own axis keeps the limb
 * on its joints but turns its stripe, which positions alone cannot show.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import { Joint, NUM_JOINTS, PARENTS } from "../src/messages.js";
import { avatarMaterials, buildAvatarGeometry, PIECES, SkinnedAvatar, stripeMaterial } from "../viewer/avatar.js";
import { poseToBones, REFERENCE_OFFSETS_M, REST_POSITIONS_M } from "../viewer/bones.js";

type Quat = [number, number, number, number];
type Vec = [number, number, number];

const qmul = ([ax, ay, az, aw]: Quat, [bx, by, bz, bw]: Quat): Quat => [
  aw * bx + ax * bw + ay * bz - az * by,
  aw * by - ax * bz + ay * bw + az * bx,
  aw * bz + ax * by - ay * bx + az * bw,
  aw * bw - ax * bx - ay * by - az * bz,
];
const axisAngle = (axis: Vec, rad: number): Quat => {
  const n = Math.hypot(...axis);
  const s = Math.sin(rad / 2) / n;
  return [axis[0] * s, axis[1] * s, axis[2] * s, Math.cos(rad / 2)];
};
/** Rotate v by unit quaternion q (xyzw). */
const rotate = (q: Quat, v: Vec): Vec => {
  const [x, y, z, w] = q;
  const tx = 2 * (y * v[2] - z * v[1]);
  const ty = 2 * (z * v[0] - x * v[2]);
  const tz = 2 * (x * v[1] - y * v[0]);
  return [v[0] + w * tx + (y * tz - z * ty), v[1] + w * ty + (z * tx - x * tz), v[2] + w * tz + (x * ty - y * tx)];
};

/** A seeded generator (mulberry32): the same poses every run. */
function random(seed: number): () => number {
  let a = seed >>> 0;
  return () => {
    a = (a + 0x6d2b79f5) >>> 0;
    let t = a;
    t = Math.imul(t ^ (t >>> 15), t | 1);
    t ^= t + Math.imul(t ^ (t >>> 7), t | 61);
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

/** FK (`server/posecast/geometry/fk.py`): random local rotations up to `maxRad`, a body `scale`. */
function randomPose(seed: number, scale: number, maxRad = 1.2): { positions: Float64Array; rotations: Float64Array } {
  const rnd = random(seed);
  const positions = new Float64Array(3 * NUM_JOINTS);
  const rotations = new Float64Array(4 * NUM_JOINTS);
  const world: Quat[] = [];
  for (let j = 0; j < NUM_JOINTS; j++) {
    const local = axisAngle([rnd() - 0.5, rnd() - 0.5, rnd() - 0.5], maxRad * (2 * rnd() - 1));
    const parent = PARENTS[j]!;
    const w = parent < 0 ? local : qmul(world[parent]!, local);
    world.push(w);
    rotations.set(w, 4 * j);
    if (parent < 0) {
      positions.set([3 * rnd() - 1.5, 0.9 + 0.2 * rnd(), 3 * rnd() - 1.5], 0);
    } else {
      const o = REFERENCE_OFFSETS_M[j]!;
      const d = rotate(world[parent]!, [o[0] * scale, o[1] * scale, o[2] * scale]);
      for (let k = 0; k < 3; k++) positions[3 * j + k] = positions[3 * parent + k]! + d[k]!;
    }
  }
  return { positions, rotations };
}

const shape = buildAvatarGeometry();
const avatar = (): SkinnedAvatar => new SkinnedAvatar(shape, avatarMaterials("#ff7a1a", stripeMaterial()));
const restRotations = (): Float64Array => {
  const r = new Float64Array(4 * NUM_JOINTS);
  for (let j = 0; j < NUM_JOINTS; j++) r[4 * j + 3] = 1;
  return r;
};

test("the rest pose gives the bind pose: scale 1, no rotation, the mesh on its joints", () => {
  const bones = poseToBones(REST_POSITIONS_M, restRotations());
  assert.ok(Math.abs(bones.scale - 1) < 1e-12, `scale ${bones.scale}`);
  const a = avatar();
  a.place(REST_POSITIONS_M, restRotations());
  const att = a.attachment(REST_POSITIONS_M);
  assert.ok(att.max_m < 1e-6 && att.bone_max_m < 1e-6, JSON.stringify(att));
});

test("poseToBones renormalises rotations and measures the body's scale", () => {
  const { positions, rotations } = randomPose(7, 1.13);
  const stretched = rotations.map((v) => v * 1.0003); // a v1 decoder's rounding, exaggerated
  const bones = poseToBones(positions, stretched);
  assert.ok(Math.abs(bones.scale - 1.13) < 1e-9, `scale ${bones.scale}`);
  for (let j = 0; j < NUM_JOINTS; j++) {
    const q = bones.rotations.subarray(4 * j, 4 * j + 4);
    assert.ok(Math.abs(Math.hypot(...q) - 1) < 1e-12);
    assert.ok(Math.abs(q[0]! - rotations[4 * j]!) < 1e-12);
  }
  assert.throws(() => poseToBones(positions.subarray(3), rotations), RangeError);
});

test("random poses at other body sizes: every ring on its joints (CPU skinning)", () => {
  const a = avatar();
  for (let seed = 1; seed <= 20; seed++) {
    const scale = 0.6 + 0.04 * seed; // 0.64 to 1.4: a child to a tall adult
    const { positions, rotations } = randomPose(seed, scale);
    a.place(positions, rotations);
    const att = a.attachment(positions);
    assert.ok(att.max_m < 1e-4, `seed ${seed}: ${JSON.stringify(att)}`);
    assert.ok(att.bone_max_m < 1e-5, `seed ${seed}: ${JSON.stringify(att)}`);
  }
});

test("a forearm rotation that disagrees with the positions tears the limb off", () => {
  const a = avatar();
  const { positions, rotations } = randomPose(3, 1.0);
  const i = 4 * Joint.LEFT_FOREARM;
  const bent = qmul(axisAngle([0.3, 1, -0.2], 1.0), [...rotations.subarray(i, i + 4)] as Quat);
  const wrong = rotations.slice();
  wrong.set(bent, i);
  a.place(positions, wrong);
  const att = a.attachment(positions);
  assert.ok(att.max_m > 0.05, JSON.stringify(att));
  assert.match(att.worst, /^LEFT_FOREARM>LEFT_HAND@/);
});

test("a twist about the forearm's own axis keeps it attached and turns its stripe as much", () => {
  const a = avatar();
  const { positions, rotations } = randomPose(5, 1.0);
  const f = 3 * Joint.LEFT_FOREARM;
  const h = 3 * Joint.LEFT_HAND;
  const elbow: Vec = [positions[f]!, positions[f + 1]!, positions[f + 2]!];
  const axis: Vec = [positions[h]! - elbow[0], positions[h + 1]! - elbow[1], positions[h + 2]! - elbow[2]];
  const n = Math.hypot(...axis);
  /** The stripe's direction from the forearm's axis, a unit vector. */
  const stripeSide = (): Vec => {
    const c = a.markCentroid("LEFT_FOREARM>LEFT_HAND");
    const v: Vec = [c.x - elbow[0], c.y - elbow[1], c.z - elbow[2]];
    const along = (v[0] * axis[0] + v[1] * axis[1] + v[2] * axis[2]) / (n * n);
    const off: Vec = [v[0] - along * axis[0], v[1] - along * axis[1], v[2] - along * axis[2]];
    const m = Math.hypot(...off);
    assert.ok(m > 0.02, `the stripe is ${m} m off the axis`);
    return [off[0] / m, off[1] / m, off[2] / m];
  };
  a.place(positions, rotations);
  const before = stripeSide();
  const i = 4 * Joint.LEFT_FOREARM;
  for (const deg of [30, 90, 150]) {
    const twisted = rotations.slice();
    twisted.set(qmul(axisAngle(axis, (deg * Math.PI) / 180), [...rotations.subarray(i, i + 4)] as Quat), i);
    a.place(positions, twisted); // the same positions: a stick figure would not change at all
    const att = a.attachment(positions);
    assert.ok(att.max_m < 1e-4, JSON.stringify(att));
    const after = stripeSide();
    const turned = (Math.acos(Math.min(1, before[0] * after[0] + before[1] * after[1] + before[2] * after[2])) * 180) / Math.PI;
    // All of it, less what the blends into the upper arm and the hand keep at the stripe's ends.
    assert.ok(turned > 0.85 * deg && turned < deg + 0.5, `a ${deg} degree twist turned the stripe ${turned} degrees`);
  }
});

test("the geometry: weights sum to 1 over the piece's bone and its neighbours; stripes where they belong", () => {
  const { geometry, marks, rings } = shape;
  const index = geometry.getAttribute("skinIndex");
  const weight = geometry.getAttribute("skinWeight");
  for (let v = 0; v < index.count; v++) {
    const sum = weight.getX(v) + weight.getY(v) + weight.getZ(v) + weight.getW(v);
    assert.ok(Math.abs(sum - 1) < 1e-6, `vertex ${v}: weights sum to ${sum}`);
    const [own, other] = [index.getX(v), index.getY(v)];
    assert.ok(own < NUM_JOINTS && other < NUM_JOINTS);
    assert.ok(other === own || PARENTS[other] === own || PARENTS[own] === other, `vertex ${v}: ${own}, ${other}`);
  }
  assert.equal(geometry.groups.length, 2);
  assert.equal(rings.filter((r) => r.t === 0).length, PIECES.length);
  const restY = (j: number): number => REST_POSITIONS_M[3 * j + 1]!;
  const position = geometry.getAttribute("position");
  const centre = (name: string): Vec => {
    const idx = marks.get(name)!;
    const c = [0, 1, 2].map((k) => idx.reduce((sum, v) => sum + position.getComponent(v, k), 0) / idx.length);
    return c as Vec;
  };
  // The backs of the forearms face up in the T-pose (palms down); shins and face forward (+Z).
  for (const side of ["LEFT", "RIGHT"]) {
    assert.ok(centre(`${side}_FOREARM>${side}_HAND`)[1] > restY(Joint.LEFT_FOREARM) + 0.02, side);
    assert.ok(centre(`${side}_SHIN>${side}_FOOT`)[2] > 0.03, side);
  }
  assert.ok(centre("HEAD>tip")[2] > 0.06);
});

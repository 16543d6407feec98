/**
 * The three.js binding (`src/three`) on the CPU, with the viewer's two generated models
 * parsed from GLB (the VRM through three-vrm's loader): fitted to a player whose
 * proportions are neither model's, every mapped bone lands on the player's FK joint for
 * random poses (hands and feet included, to a tenth of a millimetre), bone scales stay
 * uniform, a model the fit is skipped on misses the joints (so the check can fail), and
 * `AvatarRoom` adds and removes avatars on presence.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import { Vector3 } from "three";

import { fk } from "../src/records.js";
import { Joint, JOINT_NAMES, NUM_JOINTS } from "../src/messages.js";
import { REFERENCE_OFFSETS_FLAT_M } from "../src/rest.js";
import { AvatarRoom, HumanoidAvatar } from "../src/three/index.js";
import { loadHumanoid, MODELS } from "../viewer/humanoid.js";

/** A seeded generator (mulberry32), so failures reproduce. */
function rng(seed: number): () => number {
  return () => {
    seed = (seed + 0x6d2b79f5) | 0;
    let t = Math.imul(seed ^ (seed >>> 15), 1 | seed);
    t = (t + Math.imul(t ^ (t >>> 7), 61 | t)) ^ t;
    return ((t ^ (t >>> 14)) >>> 0) / 4294967296;
  };
}

/** A player unlike either model: 1.08 x the reference, long forearms, wide hips. */
function playerOffsets(): Float64Array {
  const o = REFERENCE_OFFSETS_FLAT_M.map((v) => v * 1.08);
  o[3 * Joint.LEFT_FOREARM] = 0.31;
  o[3 * Joint.RIGHT_FOREARM] = -0.31;
  o[3 * Joint.LEFT_THIGH] = 0.11;
  o[3 * Joint.RIGHT_THIGH] = -0.11;
  return o;
}

function randomPose(next: () => number, offsets: Float64Array): { positions: Float64Array; rotations: Float64Array } {
  const rotations = new Float64Array(4 * NUM_JOINTS);
  for (let j = 0; j < NUM_JOINTS; j++) {
    const [x, y, z, w] = [next() - 0.5, next() - 0.5, next() - 0.5, next() + 0.3];
    const n = Math.hypot(x, y, z, w);
    rotations.set([x / n, y / n, z / n, w / n], 4 * j);
  }
  const root = [next() * 4 - 2, 0.9 + next() * 0.2, next() * 4 - 2];
  return { positions: fk(rotations, root, offsets), rotations };
}

function worstError(avatar: HumanoidAvatar, positions: Float64Array): { max: number; joint: string } {
  avatar.object.updateMatrixWorld(true);
  const v = new Vector3();
  let max = 0;
  let joint = "";
  for (let j = 0; j < NUM_JOINTS; j++) {
    if (avatar.bone(j) === null) continue;
    avatar.jointPosition(j, v);
    const e = Math.hypot(v.x - positions[3 * j]!, v.y - positions[3 * j + 1]!, v.z - positions[3 * j + 2]!);
    if (e > max) [max, joint] = [e, JOINT_NAMES[j]!];
  }
  return { max, joint };
}

for (const kind of MODELS) {
  test(`${kind}: fitted bones land on the player's joints for random poses`, async () => {
    const { humanoid } = await loadHumanoid(kind);
    const avatar = new HumanoidAvatar(humanoid);
    const offsets = playerOffsets();
    avatar.fit(offsets);
    const next = rng(42);
    for (let k = 0; k < 50; k++) {
      const pose = randomPose(next, offsets);
      assert.ok(avatar.update(pose));
      const { max, joint } = worstError(avatar, pose.positions);
      assert.ok(max < 1e-4, `pose ${k}: ${joint} is ${(max * 1000).toFixed(2)} mm off`);
    }
    // Never culled: three.js's skinned bounds would stay where the pose was when first culled.
    let skinned = 0;
    humanoid.root.traverse((o) => {
      if ((o as { isSkinnedMesh?: boolean }).isSkinnedMesh === true) skinned += o.frustumCulled ? 100 : 1;
    });
    assert.equal(skinned, 2); // the body and its stripes, neither culled
    // Scales: uniform on every bone (a bone's mesh is scaled, never stretched).
    humanoid.root.traverse((o) => {
      assert.ok(Math.abs(o.scale.x - o.scale.y) < 1e-9 && Math.abs(o.scale.x - o.scale.z) < 1e-9, o.name);
    });
  });

  test(`${kind}: without the fit the bones miss the joints (the check can fail)`, async () => {
    const { humanoid } = await loadHumanoid(kind);
    const avatar = new HumanoidAvatar(humanoid); // fitted to the reference body only
    const offsets = playerOffsets();
    const pose = randomPose(rng(7), offsets);
    avatar.update(pose);
    assert.ok(worstError(avatar, pose.positions).max > 0.02);
  });
}

test("the glTF humanoid's proportions differ from the VRM's", async () => {
  const heights = [];
  for (const kind of MODELS) {
    const { humanoid, root } = await loadHumanoid(kind);
    root.updateMatrixWorld(true);
    const hips = humanoid.bones[Joint.PELVIS]!.getWorldPosition(new Vector3());
    const hand = humanoid.bones[Joint.LEFT_HAND]!.getWorldPosition(new Vector3());
    const arm = humanoid.bones[Joint.LEFT_UPPER_ARM]!.getWorldPosition(new Vector3());
    heights.push({ hips: hips.y, arm: hand.distanceTo(arm) });
  }
  assert.ok(Math.abs(heights[0]!.hips - heights[1]!.hips) > 0.1, JSON.stringify(heights));
  assert.ok(Math.abs(heights[0]!.arm - heights[1]!.arm) > 0.05, JSON.stringify(heights));
});

test("AvatarRoom: one avatar per player, added on join, removed on leave", async () => {
  const { Group } = await import("three");
  const parent = new Group();
  const disposed: string[] = [];
  const room = new AvatarRoom({
    parent,
    create: async () => (await loadHumanoid("gltf")).humanoid,
    dispose: (_, player) => disposed.push(player),
  });
  const member = (player: string) => ({ player, name: player });
  room.feed({
    type: "welcome",
    resumed: false,
    welcome: { type: "welcome", version: 2, player: "me", session: "s", role: "player", room: "r", t: 0, rate_hz: 60, lag_frames: 0, members: [member("me"), member("a")] } as never,
  });
  room.feed({ type: "presence", event: "join", room: "r", player: "b", name: "Bee" });
  room.feed({ type: "presence", event: "join", room: "r", player: "c", name: "Cee" });
  room.feed({ type: "presence", event: "leave", room: "r", player: "c", name: "Cee" }); // before its model is made
  await new Promise((done) => setTimeout(done, 50));
  assert.deepEqual([...room.avatars.keys()].sort(), ["a", "b"]); // never its own id
  assert.equal(parent.children.length, 2);
  const pose = randomPose(rng(3), REFERENCE_OFFSETS_FLAT_M);
  room.update(new Map([["a", pose]]));
  assert.equal(room.avatars.get("a")!.object.visible, true);
  assert.equal(room.avatars.get("b")!.object.visible, false); // no pose yet
  room.feed({ type: "presence", event: "leave", room: "r", player: "a", name: "a" });
  assert.deepEqual([...room.avatars.keys()], ["b"]);
  assert.deepEqual(disposed, ["a"]);
  assert.equal(parent.children.length, 1);
});

test("the core entry point bundles neither three.js nor the binding", async () => {
  const { build } = await import("esbuild");
  const { fileURLToPath } = await import("node:url");
  const root = fileURLToPath(new URL("../..", import.meta.url)); // .test-build/test -> the package
  const out = await build({
    entryPoints: [`${root}/src/index.ts`],
    bundle: true,
    write: false,
    metafile: true,
    format: "esm",
    platform: "neutral",
    logLevel: "silent",
  });
  const inputs = Object.keys(out.metafile.inputs);
  assert.ok(inputs.some((f) => f.endsWith("src/client.ts")), inputs.join(" "));
  assert.deepEqual(inputs.filter((f) => /three|src\/rest\.ts/.test(f)), []);
  const three = await build({
    entryPoints: [`${root}/src/three/index.ts`],
    bundle: true,
    write: false,
    metafile: true,
    format: "esm",
    platform: "neutral",
    external: ["three"],
    logLevel: "silent",
  });
  assert.deepEqual(Object.keys(three.metafile.outputs).length, 1);
  assert.ok(!Object.keys(three.metafile.inputs).some((f) => f.includes("node_modules")), "three stays external");
});

test("the WebXR example: under 60 lines, and it bundles against the package's entry points", async () => {
  const { build } = await import("esbuild");
  const { readFileSync } = await import("node:fs");
  const { fileURLToPath } = await import("node:url");
  const root = fileURLToPath(new URL("../..", import.meta.url));
  const main = `${root}/examples/webxr-avatars/main.ts`;
  const lines = readFileSync(main, "utf8").trimEnd().split("\n").length;
  assert.ok(lines < 60, `${lines} lines`);
  const out = await build({
    entryPoints: [main],
    bundle: true,
    write: false,
    format: "esm",
    platform: "browser",
    target: "es2022",
    alias: { "@posecast/client/three": `${root}/src/three/index.ts`, "@posecast/client": `${root}/src/index.ts` },
    logLevel: "silent",
  });
  assert.equal(out.errors.length, 0);
  assert.ok(out.outputFiles[0]!.text.includes("recording.json"));
});

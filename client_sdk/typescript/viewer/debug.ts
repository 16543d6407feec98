/**
 * Debug hooks for tests and the curious (`window.posecastViewer`): what the page shows,
 * without parsing pixels or DOM (players, how the skinned meshes sit on their joints,
 * their bones on the screen), switches (mode, freeze, interpolation, tampered bones),
 * the models' read-back (`tracking.ts`), and a benchmark of the three.js binding.
 * `tests/system/test_viewer.py` drives them through `scripts/viewer-check.mjs`.
 */

import { Quaternion, Vector3 } from "three";

import { Joint, type JointName } from "../src/messages.js";
import { HumanoidAvatar } from "../src/three/index.js";
import { PIECES } from "./avatar.js";
import { REFERENCE_OFFSETS_M } from "./bones.js";
import { loop } from "./frame.js";
import { mode, modelKind, setMode } from "./hud.js";
import { loadHumanoid } from "./humanoid.js";
import { client } from "./network.js";
import { room } from "./page.js";
import { type Avatar, avatars, type Drawn, models, tampered } from "./players.js";
import { camera, canvas } from "./scene.js";
import type { Track } from "./tracking.js";

/**
 * A pixel of a player's colour farther than this beyond every piece of the player's body
 * (its half-width around the streamed bone) is a stray.
 */
const STRAY_MARGIN_M = 0.04;

/** The benchmark's avatars (not in the scene) and the poses it drives them with. */
let bench: { avatars: HumanoidAvatar[]; poses: Drawn[] } | undefined;

const tipWorld = new Vector3();
const tipRot = new Quaternion();

/**
 * The pieces of the body that avatar `a` shows, as screen segments in CSS pixels `[x0,
 * y0, x1, y1, reach]` between the streamed joints, `reach` being the piece's largest
 * half-width (its ends are as round) plus {@link STRAY_MARGIN_M}, in pixels at the
 * nearer end: every pixel of an attached mesh lies within reach of one of them. The
 * tips of the leaf pieces (head, hands, toes), where no joint is streamed, follow their
 * bones. For sticks: the pieces between joints, with a reach of 15 cm.
 */
function screenBones(a: Avatar): number[][] {
  const shown = a.shown;
  if (shown === undefined) return [];
  const p = shown.pose.positions;
  const w = canvas.clientWidth;
  const h = canvas.clientHeight;
  const focal = h / 2 / Math.tan((camera.fov * Math.PI) / 360); // pixels per metre at 1 m depth
  const toScreen = (v: Vector3): [number, number, number] => {
    const depth = -v.clone().applyMatrix4(camera.matrixWorldInverse).z;
    v.project(camera);
    return [((v.x + 1) / 2) * w, ((1 - v.y) / 2) * h, depth];
  };
  const bones = a.skinned.current;
  const segments: number[][] = [];
  for (const piece of PIECES) {
    const j = Joint[piece.bone];
    const from = new Vector3(p[3 * j]!, p[3 * j + 1]!, p[3 * j + 2]!);
    let to: Vector3;
    if (typeof piece.to === "string") {
      const c = Joint[piece.to];
      to = new Vector3(p[3 * c]!, p[3 * c + 1]!, p[3 * c + 2]!);
    } else if (shown.as === "mesh") {
      tipRot.fromArray(bones.rotations, 4 * j);
      to = tipWorld.set(...piece.to).multiplyScalar(bones.scale).applyQuaternion(tipRot).add(from).clone();
    } else {
      continue;
    }
    const [x0, y0, d0] = toScreen(from);
    const [x1, y1, d1] = toScreen(to);
    const reach = (shown.as === "mesh" ? Math.max(...piece.r0, ...piece.r1) : 0.11) + STRAY_MARGIN_M;
    segments.push([x0, y0, x1, y1, (reach * focal) / Math.max(0.05, Math.min(d0, d1))]);
  }
  return segments;
}

/** For tests and the curious: what the page shows, without parsing pixels or DOM. */
export function installHooks(): void {
  Object.assign(window, {
    posecastViewer: {
      room,
      get frames() {
        return loop.frames;
      },
      get state() {
        return client?.state ?? "connecting";
      },
      get mode() {
        return mode;
      },
      setMode,
      freeze(on: boolean) {
        loop.freezing = on && !loop.frozen;
        loop.frozen = on;
      },
      tamper(joint: JointName, q: [number, number, number, number] | null) {
        if (q === null) tampered.delete(Joint[joint]);
        else tampered.set(Joint[joint], new Quaternion(...q).normalize());
      },
      players: () =>
        [...avatars.values()].map((a) => ({
          player: a.player,
          name: a.name,
          color: a.color,
          drawn: a.skinned.mesh.visible || a.sticks.visible || models.avatars.get(a.player)?.object.visible === true,
          shown: a.shown?.as ?? null,
        })),
      /** Per player: how far the skinned mesh is from the joints it was placed from (`avatar.ts`). */
      skin: () =>
        [...avatars.values()]
          .filter((a) => a.shown?.as === "mesh")
          .map((a) => ({ player: a.player, scale: a.skinned.current.scale, ...a.skinned.attachment(a.shown!.pose.positions) })),
      /** Per player: its bones on the screen (see screenBones). */
      screen: () => [...avatars.values()].map((a) => ({ player: a.player, segments: screenBones(a) })),
      /** The reference body's rest offsets the mesh is built on (tests compare them with the server's). */
      restOffsets: () => REFERENCE_OFFSETS_M.map((o) => [...o]),
      model: modelKind,
      interpolate(on: boolean) {
        loop.interpolate = on;
      },
      /** Per player, over `seconds` of drawn frames: see Track. */
      async track(seconds: number) {
        const into = new Map<string, Track>();
        loop.tracking = into;
        await new Promise((done) => setTimeout(done, seconds * 1000));
        loop.tracking = undefined;
        return [...into].map(([player, { last: _, ...t }]) => ({ player, ...t }));
      },
      /**
       * The benchmark, step 1: `n` models (VRM and glTF in turn), each fitted to a player's
       * skeleton, driven by the players' newest poses; the page stops drawing meanwhile.
       */
      async benchPrepare(n: number) {
        const c = client;
        if (c === undefined || c.poses.size === 0) throw new Error("no poses to drive the benchmark with");
        loop.benching = true;
        const poses = [...c.poses.values()].filter((p) => p.rotations !== undefined);
        const players = [...c.poses.keys()];
        const made: HumanoidAvatar[] = [];
        for (let k = 0; k < n; k++) {
          const avatar = new HumanoidAvatar((await loadHumanoid(k % 2 === 0 ? "vrm" : "gltf")).humanoid);
          const skeleton = c.skeletonOf(players[k % players.length]!);
          if (skeleton !== undefined) avatar.fit(skeleton);
          made.push(avatar);
        }
        bench = { avatars: made, poses };
        return { avatars: made.length, poses: poses.length };
      },
      /**
       * Step 2, one synchronous run (nothing else runs meanwhile): `frames` frames, each
       * driving every avatar from a pose (the players' poses in turn), timed alone and
       * with three.js's matrix update (what a render adds); `allocate` hands each avatar a
       * pose whose rotations getter copies them, an allocation per avatar per frame inside
       * the update path, which the heap check must see.
       */
      benchRun(count: number, allocate: boolean) {
        const b = bench!;
        const nPoses = b.poses.length;
        const copying = b.poses.map((p) => ({
          positions: p.positions,
          get rotations() {
            return p.rotations!.slice();
          },
        }));
        let updateMs = 0;
        let matricesMs = 0;
        for (let f = 0; f < count; f++) {
          const t0 = performance.now();
          for (let k = 0; k < b.avatars.length; k++) {
            b.avatars[k]!.update((allocate ? copying : b.poses)[(k + f) % nPoses]!);
          }
          const t1 = performance.now();
          for (let k = 0; k < b.avatars.length; k++) b.avatars[k]!.object.updateMatrixWorld(true);
          updateMs += t1 - t0;
          matricesMs += performance.now() - t1;
        }
        return { frames: count, avatars: b.avatars.length, update_ms_per_frame: updateMs / count, matrices_ms_per_frame: matricesMs / count };
      },
      benchEnd() {
        bench = undefined;
        loop.benching = false;
      },
    },
  });
}

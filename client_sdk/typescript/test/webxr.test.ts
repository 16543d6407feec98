/// <reference types="webxr" />
/**
 * fromXRFrame with a fake XRFrame: which pose lands in which slot, positions pass
 * through unchanged, orientations turn from WebXR's -Z forward to posecast's +Z.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import { toTrackers, type TrackerPose } from "../src/trackers.js";
import { fromXRFrame, xrToPosecast, type XRFrameLike, type XRRigidTransformLike } from "../src/webxr.js";

type Quat = [number, number, number, number];
type Vec = [number, number, number];

function transform(p: Vec, q: Quat): XRRigidTransformLike {
  return {
    position: { x: p[0], y: p[1], z: p[2], w: 1 },
    orientation: { x: q[0], y: q[1], z: q[2], w: q[3] },
  };
}

/** Rotate v by unit quaternion q (xyzw). */
function rotate(q: readonly number[], v: Vec): Vec {
  const [x, y, z, w] = q as Quat;
  const [vx, vy, vz] = v;
  // t = 2 * cross(q.xyz, v); v' = v + w * t + cross(q.xyz, t)
  const tx = 2 * (y * vz - z * vy);
  const ty = 2 * (z * vx - x * vz);
  const tz = 2 * (x * vy - y * vx);
  return [vx + w * tx + (y * tz - z * ty), vy + w * ty + (z * tx - x * tz), vz + w * tz + (x * ty - y * tx)];
}

function close(a: readonly number[], b: readonly number[], tol = 1e-12): void {
  assert.equal(a.length, b.length);
  a.forEach((v, i) => assert.ok(Math.abs(v - b[i]!) <= tol, `${a} != ${b}`));
}

const yaw = (deg: number): Quat => {
  const h = (deg * Math.PI) / 360;
  return [0, Math.sin(h), 0, Math.cos(h)];
};

const REF = { name: "local-floor" };
const LEFT_GRIP = { name: "left grip" };
const RIGHT_GRIP = { name: "right grip" };
const WAIST_SPACE = { name: "waist tracker" };

function fakeFrame(poses: Map<object, XRRigidTransformLike>, viewer: XRRigidTransformLike | null): XRFrameLike {
  return {
    predictedDisplayTime: 12_345.5,
    session: {
      inputSources: [
        { handedness: "left", gripSpace: LEFT_GRIP },
        { handedness: "right", gripSpace: RIGHT_GRIP },
        { handedness: "none", gripSpace: { name: "gamepad" } },
        { handedness: "right" }, // a second right source without a grip (e.g. gaze)
      ],
    },
    getViewerPose: (space) => {
      assert.equal(space, REF);
      return viewer === null ? null : { transform: viewer };
    },
    getPose: (space, base) => {
      assert.equal(base, REF);
      const t = poses.get(space);
      return t === undefined ? null : { transform: t };
    },
  };
}

test("viewer -> head, grips -> hands by handedness, caller's space -> waist", () => {
  const head = transform([0.1, 1.62, -0.3], yaw(30));
  const left = transform([0.3, 1.1, -0.4], [0.1, 0.2, 0.3, Math.sqrt(1 - 0.14)]);
  const right = transform([-0.25, 1.05, -0.35], yaw(-45));
  const waist = transform([0.05, 0.98, -0.2], yaw(10));
  const frame = fakeFrame(new Map([[LEFT_GRIP, left], [RIGHT_GRIP, right], [WAIST_SPACE, waist]]), head);
  const out = fromXRFrame(frame, REF, { waist: WAIST_SPACE });
  const slots: [TrackerPose | null | undefined, XRRigidTransformLike][] = [
    [out.head, head], [out.leftHand, left], [out.rightHand, right], [out.waist, waist],
  ];
  for (const [got, src] of slots) {
    assert.ok(got);
    // Positions pass through unchanged: same handedness, same +Y up, metres.
    assert.deepEqual(got.position, [src.position.x, src.position.y, src.position.z]);
  }
  assert.equal(out.t, 12.3455);
  const { valid } = toTrackers(out);
  assert.equal(valid, 0b1111);
});

test("orientation: posecast forward (+Z) is where the WebXR pose looks (-Z)", () => {
  for (const q of [yaw(0), yaw(90), yaw(-135), [0.1, 0.2, 0.3, Math.sqrt(1 - 0.14)] as Quat]) {
    const got = xrToPosecast(transform([0, 0, 0], q)).orientation;
    close(rotate(got, [0, 0, 1]), rotate(q, [0, 0, -1])); // forward
    close(rotate(got, [0, 1, 0]), rotate(q, [0, 1, 0])); // up stays up
    close(rotate(got, [1, 0, 0]), rotate(q, [-1, 0, 0])); // character's left = viewer's left
    close([Math.hypot(...got)], [1]);
  }
  // A viewer at identity looks down world -Z; the posecast head then faces -Z: yaw 180.
  close(xrToPosecast(transform([0, 0, 0], [0, 0, 0, 1])).orientation, [0, 1, 0, 0]);
  // A viewer turned to look down world +Z is a posecast head at rest (identity, up to sign).
  const q = xrToPosecast(transform([0, 0, 0], yaw(180))).orientation;
  close(q.map(Math.abs), [0, 0, 0, 1], 1e-12);
});

test("what the frame cannot locate is left out and sent as untracked", () => {
  const frame = fakeFrame(new Map([[RIGHT_GRIP, transform([0, 1, 0], yaw(0))]]), null);
  const out = fromXRFrame(frame, REF);
  assert.equal(out.head, undefined);
  assert.equal(out.leftHand, undefined);
  assert.ok(out.rightHand);
  assert.equal(out.waist, undefined);
  const { trackers, valid } = toTrackers(out);
  assert.equal(valid, 0b0100);
  assert.deepEqual(trackers[0], [0, 0, 0, 0, 0, 0, 1]);
});

test("a waist given as a pose is converted like any WebXR pose", () => {
  const waist = transform([0, 1, 0.5], yaw(90));
  const out = fromXRFrame(fakeFrame(new Map(), null), REF, { waist });
  assert.deepEqual(out.waist, xrToPosecast(waist));
});

test("a real XRFrame (lib webxr types) satisfies XRFrameLike", () => {
  const typed = (f: XRFrame, s: XRReferenceSpace, w: XRSpace) => fromXRFrame(f, s, { waist: w });
  assert.equal(typeof typed, "function");
});

test("a controller that lost tracking (emulatedPosition) is sent untracked, not frozen", () => {
  // A controller out of the cameras' view: the browser still gives a pose, its position
  // held or dead-reckoned (XRPose.emulatedPosition true). That is not where the hand is.
  const held = transform([0.3, 1.1, -0.4], yaw(0));
  const live = transform([-0.3, 1.1, -0.4], yaw(0));
  const waist = transform([0, 0.98, 0], yaw(0));
  const frame: XRFrameLike = {
    session: { inputSources: [{ handedness: "left", gripSpace: LEFT_GRIP }, { handedness: "right", gripSpace: RIGHT_GRIP }] },
    getViewerPose: () => ({ transform: transform([0, 1.6, 0], yaw(0)), emulatedPosition: false }),
    getPose: (space) =>
      space === LEFT_GRIP
        ? { transform: held, emulatedPosition: true }
        : space === WAIST_SPACE
          ? { transform: waist, emulatedPosition: true }
          : { transform: live, emulatedPosition: false },
  };
  const out = fromXRFrame(frame, REF, { waist: WAIST_SPACE });
  assert.equal(out.leftHand, undefined);
  assert.equal(out.waist, undefined);
  assert.ok(out.rightHand);
  assert.ok(out.head);
  assert.equal(toTrackers(out).valid, 0b0101);
});

/**
 * Tracker sets in the TypeScript SDK: the server's parsing rule, `sites` rows by site
 * name, `sites` frames and T-poses on the wire, and fromXRFrame's body sites.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import { decode, encode } from "../src/codec.js";
import { BadFieldError, NotNormalisedError, OutOfRangeError } from "../src/errors.js";
import type { Frame, Tracker } from "../src/messages.js";
import { parseTrackerSet, SITES, toSites, trackerSetOf } from "../src/sites.js";
import { fromXRFrame, type XRFrameLike, type XRRigidTransformLike } from "../src/webxr.js";

const SIX = "head,left_hand,right_hand,waist,left_foot,right_foot";
const IMU = "head,left_hand,right_hand,left_foot:imu,right_foot:imu";
const ID = [0, 0, 0, 1] as const;

test("sets parse by the server's rule and say why not", () => {
  const set = parseTrackerSet(IMU);
  assert.deepEqual(set.sites, ["head", "left_hand", "right_hand", "left_foot", "right_foot"]);
  assert.deepEqual(set.inertial, [false, false, false, true, true]);
  assert.equal(SITES.length, 10);
  for (const [text, why] of [
    ["head,left_hand", /needs a 'right_hand'/],
    ["head,left_hand,right_hand,tail", /unknown site 'tail'/],
    ["head,left_hand,right_hand,waist,waist", /listed twice/],
    ["head:imu,left_hand,right_hand", /positional 'head'/],
    ["", /non-empty/],
  ] as const) {
    assert.throws(() => parseTrackerSet(text), why);
  }
  assert.equal(trackerSetOf("hmd3"), undefined);
  assert.equal(trackerSetOf(undefined), undefined);
});

test("toSites puts each site on its row, IMUs send accelerations", () => {
  const set = parseTrackerSet(IMU);
  const { sites, valid } = toSites(set, {
    rightHand: { position: [0.3, 1.1, 0.2], orientation: [0, 0, 0, 2] },
    head: { position: [0, 1.7, 0], orientation: ID },
    leftHand: { position: [-0.3, 1.1, 0.2], orientation: ID },
    rightFoot: { acceleration: [0.5, 9.0, -1.5], orientation: ID },
  });
  assert.equal(valid, 0b10111); // left foot untracked
  assert.deepEqual(sites[2], [0.3, 1.1, 0.2, 0, 0, 0, 1]); // normalised
  assert.deepEqual(sites[3], [0, 0, 0, 0, 0, 0, 1]);
  assert.deepEqual(sites[4], [0.5, 9.0, -1.5, 0, 0, 0, 1]);
  assert.throws(
    () => toSites(set, { leftFoot: { position: [0, 0, 0], orientation: ID } }),
    /acceleration/,
  );
  assert.throws(
    () => toSites(set, { head: { position: [0, 1e4, 0], orientation: ID } }),
    OutOfRangeError,
  );
  assert.throws(
    () => toSites(set, { head: { position: [0, 1, 0], orientation: [0, 0, 0, 0] } }),
    NotNormalisedError,
  );
});

test("sites frames, set hellos and set T-poses round trip; bad ones get their codes", () => {
  const rows: Tracker[] = Array.from({ length: 6 }, (_, i) => [0.125 * i, 1, 0.5, 0, 0, 0, 1]);
  const frame: Frame = { type: "frame", seq: 3, t: 1.5, sites: rows, valid: 0b110111 };
  const back = decode(encode(frame));
  assert.ok(back.type === "frame" && "sites" in back);
  assert.equal(back.valid, 0b110111);
  assert.deepEqual(back.sites[3], [0, 0, 0, 0, 0, 0, 1]); // untracked: origin + identity
  const full = decode(encode({ type: "frame", seq: 4, t: 1.6, sites: rows }));
  assert.ok(full.type === "frame" && "sites" in full && full.valid === undefined);
  const hello = decode(encode({ type: "hello", version: 1, token: "t", room: "r", name: "n", layout: SIX }));
  assert.ok(hello.type === "hello" && hello.layout === SIX);
  const tpose = decode(encode({ type: "calibrate", tpose: true, sites: rows }));
  assert.ok(tpose.type === "calibrate" && "sites" in tpose && tpose.sites.length === 6);
  assert.throws(
    () => decode(encode({ type: "hello", version: 1, token: "t", room: "r", name: "n", layout: "head" }),),
    (e: unknown) => e instanceof BadFieldError && e.field === "layout",
  );
  assert.throws(
    () => decode(encode({ type: "frame", seq: 1, t: 1, sites: rows.slice(0, 3), valid: 0b1000 })),
    (e: unknown) => e instanceof OutOfRangeError && e.field === "valid",
  );
});

function transform(x: number, y: number, z: number): XRRigidTransformLike {
  return { position: { x, y, z, w: 1 }, orientation: { x: 0, y: 0, z: 0, w: 1 } };
}

test("fromXRFrame locates a set's body trackers like the waist", () => {
  const spaces = new Map<object, XRRigidTransformLike>();
  const foot = {};
  spaces.set(foot, transform(0.1, 0.08, 0.0));
  const frame: XRFrameLike = {
    session: { inputSources: [] },
    getViewerPose: () => ({ transform: transform(0, 1.7, 0) }),
    getPose: (space) => {
      const t = spaces.get(space);
      return t ? { transform: t } : null;
    },
  };
  const input = fromXRFrame(frame, {}, { sites: { leftFoot: foot, rightFoot: transform(-0.1, 0.08, 0) } });
  assert.deepEqual(input.leftFoot?.position, [0.1, 0.08, 0.0]);
  assert.deepEqual(input.rightFoot?.position, [-0.1, 0.08, 0]);
  const { valid } = toSites(parseTrackerSet(SIX), input);
  assert.equal(valid, 0b110001); // head and both feet; no controllers, no waist located
});

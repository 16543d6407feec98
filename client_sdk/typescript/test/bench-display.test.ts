/**
 * The latency benchmark's display bookkeeping (bench/display.ts), on the cases of the
 * Python module's tests (tests/offline/evaluation/latency/test_display.py): when a
 * received pose is first displayed, and joint jumps per nominal display frame.
 */

import assert from "node:assert/strict";
import { test } from "node:test";

import { type Displayed, DisplayWatch, JumpMeter } from "../bench/display.js";
import { Interpolator } from "../src/interp.js";

function frame(w: DisplayWatch, now: number, shown: Record<string, number>): Displayed[] {
  const out: Displayed[] = [];
  w.frame(now, new Map(Object.entries(shown)), out);
  return out;
}

test("a pose is displayed on the first frame whose shown time reaches it", () => {
  const w = new DisplayWatch();
  w.received("a", 7, 1.0, 1.01);
  w.received("a", 8, 1.02, 1.03);
  assert.deepEqual(frame(w, 1.05, { a: 0.999 }), []); // shown time short of both
  assert.deepEqual(frame(w, 1.06, { a: 1.0 }), [["a", 7, 1.0, 1.01, 1.06]]);
  assert.deepEqual(frame(w, 1.07, { a: 1.019 }), []); // 7 is not shown twice
  assert.deepEqual(frame(w, 1.08, { a: 5.0 }), [["a", 8, 1.02, 1.03, 1.08]]);
  assert.deepEqual(w.waiting(), []);
});

test("a late pose is displayed on the next frame, and senders are apart", () => {
  const w = new DisplayWatch();
  assert.deepEqual(frame(w, 2.0, { a: 1.5, b: 1.5 }), []);
  w.received("a", 1, 1.4, 2.005); // arrives after the shown time passed it
  w.received("b", 1, 1.6, 2.005);
  w.received("b", 0, 1.55, 2.006); // out of order: kept sorted by t
  assert.deepEqual(frame(w, 2.011, { a: 1.511, b: 1.58 }), [
    ["a", 1, 1.4, 2.005, 2.011],
    ["b", 0, 1.55, 2.006, 2.011],
  ]);
  assert.deepEqual(w.waiting(), [["b", 1, 1.6, 2.005]]);
  w.forget("b"); // left: never displayed
  assert.deepEqual(w.waiting(), []);
});

test("the SDK interpolator displays every pose once, in order", () => {
  const interp = new Interpolator();
  const w = new DisplayWatch();
  const shownAt = new Map<number, number>(); // frame time -> shown time
  const displayed: Displayed[] = [];
  let kPose = 0;
  for (let f = 0; f < 180; f++) { // two seconds at 90 Hz; one clock (server = client)
    const now = f / 90;
    while (kPose / 60 <= now && kPose < 90) { // 1.5 s of poses, each on time
      const t = kPose / 60;
      const positions = new Float64Array(57);
      positions[0] = t;
      interp.push({ player: "a", seq: kPose, t, positions });
      w.received("a", kPose, t, t);
      kPose++;
    }
    const s = interp.posesAt(now).get("a")!;
    shownAt.set(now, s.t);
    w.frame(now, new Map([["a", s.t]]), displayed);
  }
  assert.deepEqual(displayed.map((d) => d[1]), [...Array(90).keys()]); // each once, in order
  const frames = [...shownAt.keys()];
  for (const [, , t, received, shown] of displayed) {
    const i = frames.indexOf(shown);
    assert.ok(shownAt.get(shown)! >= t && shown >= received);
    assert.ok(i === 0 || shownAt.get(frames[i - 1]!)! < t || frames[i - 1]! < received);
  }
});

test("jumps are per nominal frame and only in the window", () => {
  const m = new JumpMeter(100);
  const at = (y: number, x = 0): Float64Array => Float64Array.from([x, y, 0, 0, 0, 0]); // 2 joints
  m.frame(0.0, new Map([["a", at(0)]]), false);
  m.frame(0.01, new Map([["a", at(0.03)]])); // on time: 3 cm
  m.frame(0.03, new Map([["a", at(0.07)]])); // two periods late: 4 cm counts as 2
  m.frame(0.035, new Map([["a", at(0.08)]])); // early: as it is
  m.frame(0.045, new Map([["a", at(0.08)], ["b", at(0)]])); // b's first frame: no jump yet
  m.forget("a");
  m.frame(0.055, new Map([["a", at(0, 5)]])); // a after forget: no jump
  const want = [0.03, 0.02, 0.01, 0.0];
  assert.equal(m.jumpsM.length, want.length);
  m.jumpsM.forEach((j, i) => assert.ok(Math.abs(j - want[i]!) < 1e-12, `${j} vs ${want[i]}`));
});

test("the meter keeps its own copy of a frame's positions (samples are reused)", () => {
  const m = new JumpMeter(100);
  const shared = new Float64Array(3);
  m.frame(0.0, new Map([["a", shared]]));
  shared[0] = 0.05; // the caller's sample array, refilled for the next frame
  m.frame(0.01, new Map([["a", shared]]));
  assert.ok(Math.abs(m.jumpsM[0]! - 0.05) < 1e-12);
});

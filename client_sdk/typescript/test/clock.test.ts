/**
 * ClockSync: the spec's offset and rtt, the smallest-rtt sample wins, and the display
 * clock (the shared table proto/vectors/sdk/clock.json, which the Python SDK writes).
 */

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { describe, test } from "node:test";

import { ClockSync } from "../src/clock.js";
import { repoRoot } from "./helpers.js";

test("offset and rtt follow proto/README.md", () => {
  const c = new ClockSync();
  // server = client + 100; 10 ms each way; the server holds it 2 ms.
  const s = c.add(5.0, 105.01, 105.012, 5.022);
  assert.ok(s !== undefined);
  assert.ok(Math.abs(s.offsetS - 100) < 1e-9);
  assert.ok(Math.abs(s.rttS - 0.02) < 1e-9);
  assert.ok(Math.abs(c.toServer(6) - 106) < 1e-9);
  assert.ok(Math.abs(c.toClient(106) - 6) < 1e-9);
});

test("the sample with the smallest rtt among the last `window` wins", () => {
  const c = new ClockSync(3);
  assert.equal(c.offsetS, undefined);
  assert.throws(() => c.toServer(1));
  c.add(0, 100.001, 100.001, 0.002); // rtt 2 ms, offset 100
  c.add(1, 101.2, 101.2, 1.25); // rtt 250 ms, offset skewed by the slow way out
  assert.ok(Math.abs(c.offsetS! - 100) < 1e-9);
  c.add(2, 102.1, 102.1, 2.2);
  c.add(3, 103.1, 103.1, 3.2); // the 2 ms sample has left the window
  assert.ok(Math.abs(c.rttS! - 0.2) < 1e-9);
  c.reset();
  assert.equal(c.best, undefined);
});

test("displayTime throws before a pong (as toServer does), then snaps onto the estimate", () => {
  const c = new ClockSync();
  assert.throws(() => c.displayTime(1), /no clock sample/);
  c.add(5.0, 105.01, 105.012, 5.022);
  assert.equal(c.displayTime(6), c.toServer(6));
  assert.equal(c.displayOffsetS, c.offsetS);
});

test("displayTime slews a step of the estimate at 0.5 % and never goes back", () => {
  const c = new ClockSync();
  c.add(1.0, 51.03, 51.0302, 1.0322); // offset 50 + 14 ms (rtt 32 ms)
  const shown = [c.displayTime(2)];
  c.add(2.0, 52.001, 52.0012, 2.0302); // better (rtt 30 ms): 50 - 14 ms, a -28 ms step
  for (let k = 1; k <= 900; k++) shown.push(c.displayTime(2 + k / 90));
  for (let k = 1; k < shown.length; k++) {
    const step = shown[k]! - shown[k - 1]!;
    assert.ok(step >= 0.995 / 90 - 1e-9 && step <= 1 / 90 + 1e-9, `frame ${k}: ${step}`);
  }
  assert.ok(Math.abs(shown[900]! - c.toServer(12)) < 1e-12, "converged 5.6 s later");
});

test("displayTime snaps beyond snapS; reset() forgets it; bad options are refused", () => {
  const c = new ClockSync(8, 0.005, 0.05);
  c.add(1, 8.01, 8.01, 1.02); // offset 7
  c.displayTime(1.5);
  c.add(2, 9.061, 9.061, 2.002); // the server's clock stepped by 60 ms
  assert.equal(c.displayTime(2.5), c.toServer(2.5));
  c.reset();
  assert.equal(c.displayOffsetS, undefined);
  assert.throws(() => c.displayTime(3));
  assert.throws(() => new ClockSync(8, -0.1), RangeError);
  assert.throws(() => new ClockSync(8, 1), RangeError);
  assert.throws(() => new ClockSync(8, 0.005, -1), RangeError);
});

type ClockStep =
  | { reset: true }
  | { add: [number, number, number, number]; offset_s: number }
  | { display: number; expect: number | null; rule: string };
const CLOCK_TABLE = JSON.parse(
  readFileSync(join(repoRoot(), "proto", "vectors", "sdk", "clock.json"), "utf8"),
) as {
  tolerance: number;
  cases: { name: string; config: { window: number; slew_rate: number; snap_s: number }; steps: ClockStep[] }[];
};

describe("proto/vectors/sdk/clock.json", () => {
  for (const c of CLOCK_TABLE.cases) {
    test(c.name, () => {
      const clock = new ClockSync(c.config.window, c.config.slew_rate, c.config.snap_s);
      const tol = CLOCK_TABLE.tolerance;
      c.steps.forEach((step, k) => {
        if ("reset" in step) clock.reset();
        else if ("add" in step) {
          clock.add(...step.add);
          assert.ok(Math.abs(clock.offsetS! - step.offset_s) <= tol, `step ${k} offset`);
        } else if (step.expect === null) {
          assert.throws(() => clock.displayTime(step.display), `step ${k} before a pong`);
        } else {
          const got = clock.displayTime(step.display);
          assert.ok(Math.abs(got - step.expect) <= tol, `step ${k} (${step.rule}): want ${step.expect}, got ${got}`);
        }
      });
    });
  }
});

test("an absurd exchange is refused and kept out of the estimate, as in Python and C#", () => {
  const c = new ClockSync();
  assert.equal(c.add(10, 110, 110.01, 9), undefined); // pong before its ping
  assert.equal(c.add(10, 110, 111, 10.5), undefined); // negative round trip
  assert.equal(c.offsetS, undefined);
  assert.ok(c.add(10, 110, 110, 10.2) !== undefined);
  assert.ok(Math.abs((c.offsetS ?? 0) - 99.9) < 1e-9);
});

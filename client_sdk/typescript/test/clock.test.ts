/** ClockSync: the spec's offset and rtt, and the smallest-rtt sample wins. */

import assert from "node:assert/strict";
import { test } from "node:test";

import { ClockSync } from "../src/clock.js";

test("offset and rtt follow proto/README.md", () => {
  const c = new ClockSync();
  // server = client + 100; 10 ms each way; the server holds it 2 ms.
  const s = c.add(5.0, 105.01, 105.012, 5.022);
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

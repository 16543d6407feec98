/**
 * The adaptive render delay: the shared table proto/vectors/sdk/delay.json (written
 * from the Python SDK, which runs it too, as does C#), and RenderDelay's window.
 */

import assert from "node:assert/strict";
import { readFileSync } from "node:fs";
import { join } from "node:path";
import { describe, test } from "node:test";

import { PoseBuffer, PoseSample } from "../src/interp.js";
import { nearestRank, RenderDelay } from "../src/render-delay.js";
import { interpOptions, repoRoot } from "./helpers.js";

interface Expect {
  delay_s: number;
  target_s: number | null;
  t: number;
  mode: string;
}
type Step = { push: [number, number] } | { query: number; expect: Expect | null };
const TABLE = JSON.parse(
  readFileSync(join(repoRoot(), "proto", "vectors", "sdk", "delay.json"), "utf8"),
) as { tolerance: number; cases: { name: string; config: Record<string, number | boolean>; steps: Step[] }[] };

describe("proto/vectors/sdk/delay.json", () => {
  for (const c of TABLE.cases) {
    test(c.name, () => {
      const tol = TABLE.tolerance;
      const buf = new PoseBuffer(interpOptions(c.config));
      const out = new PoseSample(); // the allocation-free path: the same answers
      const near = (a: number, b: number): boolean => Math.abs(a - b) <= tol;
      c.steps.forEach((step, k) => {
        if ("push" in step) {
          const [seq, t] = step.push;
          buf.push({ player: "p", seq, t, positions: [t - 100, 1, 0] });
          return;
        }
        const shown = buf.poseAtInto(step.query, out);
        const want = step.expect;
        if (want === null) {
          assert.equal(shown, false, `step ${k}`);
          return;
        }
        assert.ok(shown, `step ${k}`);
        assert.equal(out.mode, want.mode, `step ${k}`);
        assert.ok(near(out.t, want.t), `step ${k}: t ${out.t} vs ${want.t}`);
        assert.equal(buf.shownT, out.t);
        assert.ok(near(buf.delayS, want.delay_s), `step ${k}: delay ${buf.delayS} vs ${want.delay_s}`);
        if (want.target_s === null) assert.equal(buf.targetDelayS, undefined, `step ${k}`);
        else assert.ok(near(buf.targetDelayS!, want.target_s), `step ${k}: target`);
      });
    });
  }
});

test("the table's first config is the SDK's defaults", () => {
  const buf = new PoseBuffer(interpOptions(TABLE.cases[0]!.config));
  assert.deepEqual(buf.options, new PoseBuffer().options);
});

test("the window keeps the last needs sorted", () => {
  let a = 15;
  const rand = (): number => ((a = (a * 1103515245 + 12345) % 2147483648) / 2147483648);
  const pool = Array.from({ length: 20 }, () => Math.round(rand() * 100) / 1000);
  const rd = new RenderDelay({ startS: 0.1, minS: 0, maxS: 10, quantile: 0.9, window: 16, marginS: 0, slew: 1 });
  const needs: number[] = [];
  for (let i = 0; i < 300; i++) {
    const v = pool[Math.floor(rand() * pool.length)]!; // repeats too
    rd.observe(v);
    needs.push(v);
    const last = needs.slice(-16).sort((x, y) => x - y);
    assert.equal(rd.targetS, nearestRank(last, last.length, 0.9));
    assert.equal(rd.samples, Math.min(needs.length, 16));
  }
});

test("slew, bounds, measures and reset", () => {
  const rd = new RenderDelay({ startS: 0.1, minS: 0.02, maxS: 0.25, quantile: 1, window: 4, marginS: 0, slew: 0.05 });
  assert.equal(rd.measures(10, 0.25), false); // the first query
  rd.advance(10);
  assert.equal(rd.delayS, 0.1);
  assert.ok(rd.measures(10.1, 0.25) && !rd.measures(10.5, 0.25) && !rd.measures(9.9, 0.25));
  rd.observe(0.03);
  rd.advance(11);
  assert.ok(Math.abs(rd.delayS - 0.05) < 1e-12);
  rd.advance(10.5); // an earlier time moves nothing
  assert.ok(Math.abs(rd.delayS - 0.05) < 1e-12);
  rd.advance(11.5);
  assert.equal(rd.delayS, 0.03);
  rd.observe(1);
  assert.equal(rd.targetS, 0.25);
  rd.reset();
  assert.deepEqual([rd.delayS, rd.targetS, rd.samples], [0.1, undefined, 0]);
  assert.equal(new PoseBuffer({ delayS: 0.5 }).delayS, 0.25);
  assert.equal(new PoseBuffer({ delayS: 0.5, adaptive: false }).delayS, 0.5);
});

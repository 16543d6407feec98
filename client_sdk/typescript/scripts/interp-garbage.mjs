// Garbage per frame of the TypeScript interpolator: 16 players at 90 Hz fed 60 Hz poses
// (19 joints with rotations, 5 ms late, every 7th held 30 ms), sampled with
// posesAt (fresh objects) and with posesAtInto (caller-owned PoseSamples). Bytes are
// counted by V8's sampling heap profiler with collected objects included, over the
// frames after a warm-up (so the code is optimised), per player per frame.
//
//   node scripts/interp-garbage.mjs [--frames 20000]
import { mkdtempSync, rmSync } from "node:fs";
import { Session } from "node:inspector/promises";
import { tmpdir } from "node:os";
import { dirname, join } from "node:path";
import { fileURLToPath, pathToFileURL } from "node:url";

import { build } from "esbuild";

const root = join(dirname(fileURLToPath(import.meta.url)), "..");
const out = mkdtempSync(join(tmpdir(), "interp-garbage-"));
await build({
  entryPoints: [join(root, "src", "interp.ts")], bundle: true, outdir: out, format: "esm",
  platform: "node", target: "node20", logLevel: "warning",
});
const { Interpolator } = await import(pathToFileURL(join(out, "interp.js")).href);
rmSync(out, { recursive: true, force: true });
const at = process.argv.indexOf("--frames");
const FRAMES = at > 0 ? Number(process.argv[at + 1]) : 20000;
const PLAYERS = 16;
const WARM = 6000;

const poses = []; // made up front: what a decoder hands over is not the buffer's garbage
for (let k = 0; k < Math.ceil(((WARM + FRAMES) * 60) / 90) + 10; k++) {
  const row = [];
  for (let p = 0; p < PLAYERS; p++) {
    const positions = new Float64Array(57);
    const rotations = new Float64Array(76);
    for (let j = 0; j < 19; j++) {
      positions.set([k / 60 + 0.01 * j, 1 + 0.1 * Math.sin(k / 20 + j), p], 3 * j);
      const a = 0.3 * Math.sin(k / 20 + j);
      rotations.set([0, Math.sin(a), 0, Math.cos(a)], 4 * j);
    }
    row.push({ player: `p${p}`, seq: k, t: 1000 + k / 60, positions, rotations });
  }
  poses.push(row);
}

async function measure(into) {
  const ip = new Interpolator();
  const samples = new Map();
  let next = 0;
  const frames = (a, b) => {
    for (let f = a; f < b; f++) {
      const now = 1000.05 + f / 90;
      while (next < poses.length && 1000 + next / 60 + (next % 7 === 3 ? 0.03 : 0.005) <= now) {
        const row = poses[next++];
        for (let p = 0; p < row.length; p++) ip.push(row[p]);
      }
      if (into) ip.posesAtInto(now, samples);
      else ip.posesAt(now);
    }
  };
  frames(0, WARM);
  const s = new Session();
  s.connect();
  await s.post("HeapProfiler.startSampling", {
    samplingInterval: 32, includeObjectsCollectedByMajorGC: true, includeObjectsCollectedByMinorGC: true,
  });
  frames(WARM, WARM + FRAMES);
  const { profile } = await s.post("HeapProfiler.stopSampling");
  s.disconnect();
  let bytes = 0;
  const walk = (n) => {
    bytes += n.selfSize;
    n.children.forEach(walk);
  };
  walk(profile.head);
  return bytes / FRAMES / PLAYERS;
}

const fresh = await measure(false);
const reused = await measure(true);
console.log(`posesAt:     ${fresh.toFixed(0)} bytes per player per frame`);
console.log(`posesAtInto: ${reused.toFixed(0)} bytes per player per frame`);

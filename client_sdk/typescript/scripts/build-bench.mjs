// Bundle the client process of `posecast bench latency --sdk typescript`
// (bench/latency-worker.ts + the SDK + ws) into ONE CommonJS file for Node, so it runs
// from a temporary folder without this package's node_modules beside it. The
// benchmark (server/posecast/offline/evaluation/latency/node_players.py) runs this
// before its first phase; nothing it writes is committed.
//
//   node scripts/build-bench.mjs --out DIR       write DIR/latency-worker.cjs
import { dirname, join, resolve } from "node:path";
import { fileURLToPath } from "node:url";

import { build } from "esbuild";

const root = join(dirname(fileURLToPath(import.meta.url)), "..");
const args = process.argv.slice(2);
const outAt = args.indexOf("--out");
if (outAt < 0 || !args[outAt + 1]) {
  console.error("usage: build-bench.mjs --out DIR");
  process.exit(2);
}
await build({
  entryPoints: [join(root, "bench", "latency-worker.ts")],
  outfile: join(resolve(args[outAt + 1]), "latency-worker.cjs"),
  bundle: true,
  format: "cjs", // ws is CommonJS: its require()s stay as they are
  platform: "node",
  target: "node20",
  external: ["bufferutil", "utf-8-validate"], // ws's optional native helpers: it runs without
  logLevel: "warning",
});

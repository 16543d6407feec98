// Transpile src/, test/, viewer/ and bench/ with esbuild (type checking is `npm run typecheck`'s job)
// into .test-build/, then run them with Node's own test runner.
//
//   node scripts/run-tests.mjs                 every test
//   node scripts/run-tests.mjs vectors webxr   only test/vectors.test.ts, test/webxr.test.ts
import { spawnSync } from "node:child_process";
import { readdirSync, rmSync } from "node:fs";
import { dirname, join } from "node:path";
import { fileURLToPath } from "node:url";

import { build } from "esbuild";

const root = join(dirname(fileURLToPath(import.meta.url)), "..");
const out = join(root, ".test-build");
const ts = (dir) =>
  readdirSync(join(root, dir))
    .filter((f) => f.endsWith(".ts"))
    .map((f) => join(root, dir, f));

rmSync(out, { recursive: true, force: true });
await build({
  // viewer/ and bench/: what their tests import
  entryPoints: [...ts("src"), ...ts("src/three"), ...ts("test"), ...ts("viewer"), ...ts("bench")],
  outdir: out,
  outbase: root,
  format: "esm",
  platform: "node",
  target: "node20",
  sourcemap: "inline",
  logLevel: "warning",
});

const only = process.argv.slice(2);
const files = readdirSync(join(out, "test"))
  .filter((f) => f.endsWith(".test.js"))
  .filter((f) => only.length === 0 || only.includes(f.replace(/\.test\.js$/, "")))
  .map((f) => join(out, "test", f));
const run = spawnSync(
  process.execPath,
  ["--enable-source-maps", "--test", "--test-reporter=dot", "--test-reporter-destination=stdout",
   "--test-reporter=spec", "--test-reporter-destination=" + join(out, "report.txt"), ...files],
  { stdio: "inherit", cwd: root },
);
if (run.status !== 0) {
  // The dot reporter only marks failures; show their details from the spec report.
  const { readFileSync } = await import("node:fs");
  const report = readFileSync(join(out, "report.txt"), "utf8").split("\n");
  const start = report.findIndex((line) => line.includes("failing tests:"));
  process.stdout.write(report.slice(start >= 0 ? start : -80).join("\n") + "\n");
}
process.exit(run.status ?? 1);

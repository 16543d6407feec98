// Bundle the live viewer (viewer/main.ts + the SDK + three.js) into ONE static file,
// server/posecast/online/shell/static/viewer.js, and copy viewer/index.html next to it. Both are
// committed: the Python server serves them as package data and needs no Node at run
// time. esbuild's output is deterministic, so the build is reproducible:
//
//   node scripts/build-viewer.mjs           rebuild the committed files
//   node scripts/build-viewer.mjs --check   fail if they differ from a fresh build
import { readFileSync, writeFileSync } from "node:fs";
import { dirname, join, relative } from "node:path";
import { fileURLToPath } from "node:url";

import { build } from "esbuild";

const root = join(dirname(fileURLToPath(import.meta.url)), "..");
const outDir = join(root, "..", "..", "server", "posecast", "online", "shell", "static");
const check = process.argv.includes("--check");

const result = await build({
  entryPoints: [join(root, "viewer", "main.ts")],
  bundle: true,
  minify: true,
  format: "esm",
  target: "es2020",
  platform: "browser",
  legalComments: "eof",
  banner: {
    js: "// posecast live viewer. Built by client_sdk/typescript/scripts/build-viewer.mjs from client_sdk/typescript/viewer/: do not edit.",
  },
  write: false,
  logLevel: "warning",
});
const files = new Map([
  [join(outDir, "viewer.js"), Buffer.from(result.outputFiles[0].contents)],
  [join(outDir, "index.html"), readFileSync(join(root, "viewer", "index.html"))],
]);

let stale = 0;
for (const [path, bytes] of files) {
  const name = relative(process.cwd(), path);
  if (check) {
    let old;
    try {
      old = readFileSync(path);
    } catch {
      old = Buffer.alloc(0);
    }
    if (!old.equals(bytes)) {
      console.error(`${name} is stale: run npm run build:viewer (in client_sdk/typescript)`);
      stale++;
    }
  } else {
    writeFileSync(path, bytes);
    console.log(`wrote ${name} (${(bytes.length / 1024).toFixed(0)} KiB)`);
  }
}
process.exit(stale ? 1 : 0);

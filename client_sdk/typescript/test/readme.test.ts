/**
 * The README's quick start is real: it is at most 15 lines of code, it type-checks
 * (strict, as a user's project would, with `@posecast/client` mapped to src/), and it
 * runs against a real `posecast serve --dev`, printing the head of its own pose.
 */

import assert from "node:assert/strict";
import { spawn, spawnSync } from "node:child_process";
import { mkdirSync, readFileSync, writeFileSync } from "node:fs";
import { join } from "node:path";
import { after, before, test } from "node:test";

import { build } from "esbuild";

import { repoRoot } from "./helpers.js";
import { mintToken, type RunningServer, serverSkipReason, startServer } from "./server.js";

const PKG = join(repoRoot(), "client_sdk", "typescript");
const OUT = join(PKG, ".test-build", "readme");

function snippet(): string {
  const readme = readFileSync(join(PKG, "README.md"), "utf8");
  const block = /```ts\n([\s\S]*?)```/.exec(readme);
  assert.ok(block, "README lost its TypeScript example");
  return block[1]!;
}

test("the quick start is at most 15 lines of code", () => {
  const lines = snippet().trim().split("\n");
  assert.ok(lines.filter((l) => l.trim() !== "").length <= 15, `${lines.length} lines`);
  assert.ok(lines.length <= 16);
});

test("the quick start type-checks (strict) against the SDK", () => {
  mkdirSync(OUT, { recursive: true });
  writeFileSync(join(OUT, "quickstart.ts"), snippet());
  writeFileSync(
    join(OUT, "tsconfig.json"),
    JSON.stringify({
      extends: "../../tsconfig.json",
      // A user's project: strict, but process.env.X is allowed (no index-signature rule).
      compilerOptions: {
        noPropertyAccessFromIndexSignature: false,
        paths: { "@posecast/client": ["../../src/index.ts"] },
      },
      files: ["quickstart.ts"],
      include: [],
    }),
  );
  const tsc = spawnSync(
    process.execPath,
    [join(PKG, "node_modules", "typescript", "bin", "tsc"), "-p", join(OUT, "tsconfig.json")],
    { encoding: "utf8" },
  );
  assert.equal(tsc.status, 0, tsc.stdout + tsc.stderr);
});

const skip = serverSkipReason();
let server: RunningServer | undefined;
before(async () => {
  if (skip === undefined) server = await startServer();
});
after(async () => {
  await server?.stop();
});

test("the quick start runs against a real server", { skip }, async () => {
  mkdirSync(OUT, { recursive: true });
  writeFileSync(join(OUT, "quickstart.ts"), snippet());
  const bundle = join(OUT, "quickstart.mjs");
  await build({
    entryPoints: [join(OUT, "quickstart.ts")],
    outfile: bundle,
    bundle: true,
    platform: "node",
    format: "esm",
    target: "node20",
    alias: { "@posecast/client": join(PKG, "src", "index.ts") },
    external: ["ws"],
    logLevel: "warning",
  });
  const s = server!;
  const env = {
    ...process.env,
    POSECAST_URL: s.url,
    POSECAST_TOKEN: mintToken(s.secret, { room: "demo", player: "ada" }),
  };
  const child = spawn(process.execPath, [bundle], { env, cwd: PKG });
  let out = "";
  child.stdout.on("data", (d: Buffer) => (out += d.toString()));
  child.stderr.on("data", (d: Buffer) => (out += d.toString()));
  const code = await new Promise<number | null>((resolve) => {
    const timer = setTimeout(() => child.kill(), 30_000);
    child.on("exit", (c) => {
      clearTimeout(timer);
      resolve(c);
    });
  });
  assert.equal(code, 0, out);
  assert.match(out, /^pose \d+: head at -?\d+\.\d\d,-?\d+\.\d\d,-?\d+\.\d\d m$/m);
});

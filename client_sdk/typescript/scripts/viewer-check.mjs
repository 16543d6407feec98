// Drive the live viewer in headless Chromium (playwright-core, the system's chromium)
// and measure what it draws. Prints one JSON line; tests/online/shell/test_viewer.py asserts.
//
//   node scripts/viewer-check.mjs URL OUT_DIR [GAP_MS] [TRIES]
//
// It waits until the page lists >= 2 players with drawn skeletons, then takes real
// screenshots GAP_MS apart (default 400). For each screenshot it counts, outside the
// HUD panel, the pixels in each player's colour (by hue: the meshes are lit, so the
// brightness varies); for each consecutive pair, the pixels that changed, and those
// that changed where a skeleton is (in a player's colour in either shot). The demo's
// walkers stand still for 2.4 s of every 12 s clip, so it keeps taking screenshots
// (up to TRIES, default 8) until a pair shows skeleton motion. It also reads the
// names on the page (player list, and the labels over the heads).
import { mkdtempSync, rmSync, writeFileSync } from "node:fs";
import { tmpdir } from "node:os";
import { join } from "node:path";

import { chromium } from "playwright-core";

const [url, outDir, gapArg, triesArg] = process.argv.slice(2);
if (!url || !outDir) {
  console.error("usage: viewer-check.mjs URL OUT_DIR [GAP_MS] [TRIES]");
  process.exit(2);
}
const gapMs = Number(gapArg ?? 400);
const tries = Number(triesArg ?? 8);
const MOVED_PIXELS = 400; // skeleton pixels that must change between two shots

/** Runs in the page: pixel statistics of two PNG screenshots (base64). */
async function analyse({ a, b }) {
  const decode = async (b64) => {
    const bytes = Uint8Array.from(atob(b64), (c) => c.charCodeAt(0));
    const bmp = await createImageBitmap(new Blob([bytes], { type: "image/png" }));
    const ctx = new OffscreenCanvas(bmp.width, bmp.height).getContext("2d");
    ctx.drawImage(bmp, 0, 0);
    return ctx.getImageData(0, 0, bmp.width, bmp.height);
  };
  const hsv = (r, g, b) => {
    const max = Math.max(r, g, b);
    const d = max - Math.min(r, g, b);
    let h = 0;
    if (d > 0) {
      if (max === r) h = ((g - b) / d) % 6;
      else if (max === g) h = (b - r) / d + 2;
      else h = (r - g) / d + 4;
    }
    return [(h * 60 + 360) % 360, max === 0 ? 0 : d / max, max / 255];
  };
  const hueOf = (hex) => {
    const n = parseInt(hex.slice(1), 16);
    return hsv((n >> 16) & 255, (n >> 8) & 255, n & 255)[0];
  };
  const players = window.posecastViewer.players();
  const hues = players.map((p) => hueOf(p.color));
  const hud = document.getElementById("hud").getBoundingClientRect();
  const [ia, ib] = [await decode(a), await decode(b)];
  const sx = ia.width / window.innerWidth;
  const sy = ia.height / window.innerHeight;
  /** Index of the player whose colour pixel i of img has, or -1. */
  const owner = (img, i) => {
    const [h, s, v] = hsv(img.data[i], img.data[i + 1], img.data[i + 2]);
    if (s < 0.35 || v < 0.2) return -1;
    return hues.findIndex((hue) => Math.min(Math.abs(h - hue), 360 - Math.abs(h - hue)) < 16);
  };
  const pixelsA = players.map(() => 0);
  const pixelsB = players.map(() => 0);
  let changed = 0;
  let changedSkeleton = 0;
  let total = 0;
  for (let y = 0; y < ia.height; y++) {
    for (let x = 0; x < ia.width; x++) {
      if (x >= hud.left * sx && x <= hud.right * sx && y >= hud.top * sy && y <= hud.bottom * sy) {
        continue; // the HUD's colour swatches are no skeleton
      }
      total++;
      const i = 4 * (y * ia.width + x);
      const oa = owner(ia, i);
      const ob = owner(ib, i);
      if (oa >= 0) pixelsA[oa]++;
      if (ob >= 0) pixelsB[ob]++;
      const d = Math.max(
        Math.abs(ia.data[i] - ib.data[i]),
        Math.abs(ia.data[i + 1] - ib.data[i + 1]),
        Math.abs(ia.data[i + 2] - ib.data[i + 2]),
      );
      if (d > 40) {
        changed++;
        if (oa >= 0 || ob >= 0) changedSkeleton++;
      }
    }
  }
  return {
    players: players.map((p, k) => ({ ...p, pixels_a: pixelsA[k], pixels_b: pixelsB[k] })),
    changed_pixels: changed,
    changed_skeleton_pixels: changedSkeleton,
    total_pixels: total,
  };
}

const profile = mkdtempSync(join(tmpdir(), "posecast-chromium-"));
// A fresh profile: playwright passes it as --user-data-dir for a persistent context.
const browser = await chromium.launchPersistentContext(profile, {
  executablePath: process.env.CHROMIUM ?? "/usr/bin/chromium",
  headless: true,
  viewport: { width: 1000, height: 640 },
  args: [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking", "--disable-component-update", "--disable-sync",
    // WebGL without a GPU: ANGLE on SwiftShader (software), allowed explicitly.
    "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
  ],
});
const logs = [];
try {
  const page = browser.pages()[0] ?? (await browser.newPage());
  page.on("console", (m) => logs.push(`${m.type()}: ${m.text()}`));
  page.on("pageerror", (e) => logs.push(`pageerror: ${e.message}`));
  await page.goto(url, { waitUntil: "load", timeout: 20_000 });
  await page.waitForFunction(
    () => {
      const v = window.posecastViewer;
      return v && v.frames > 10 && v.players().filter((p) => p.drawn).length >= 2;
    },
    null,
    { timeout: 20_000, polling: 100 },
  );
  await page.waitForTimeout(700); // let the camera settle on the players
  const shots = [await page.screenshot({ type: "png" })];
  const pairs = [];
  while (shots.length <= tries) {
    await page.waitForTimeout(gapMs);
    shots.push(await page.screenshot({ type: "png" }));
    const [a, b] = shots.slice(-2).map((s) => s.toString("base64"));
    const stats = await page.evaluate(analyse, { a, b });
    pairs.push(stats);
    if (stats.changed_skeleton_pixels >= MOVED_PIXELS) break;
  }
  const names = await page.evaluate(() => ({
    list_names: [...document.querySelectorAll("#players .name")].map((e) => e.textContent),
    label_names: [...document.querySelectorAll("#labels .label")]
      .filter((e) => !e.hidden)
      .map((e) => e.textContent),
    status: document.getElementById("status").textContent,
    frames: window.posecastViewer.frames,
  }));
  const screenshots = shots.slice(-2).map((png, i) => {
    const path = join(outDir, `viewer-${"ab"[i]}.png`);
    writeFileSync(path, png);
    return path;
  });
  console.log(JSON.stringify({ ...pairs.at(-1), pairs: pairs.length, ...names, screenshots, logs }));
} catch (err) {
  console.log(JSON.stringify({ error: String(err), logs }));
  process.exitCode = 1;
} finally {
  await browser.close();
  rmSync(profile, { recursive: true, force: true });
}

// Drive the live viewer in headless Chromium (playwright-core, the system's chromium)
// and measure what it draws. Prints one JSON line; tests/system/test_viewer.py asserts.
//
//   node scripts/viewer-check.mjs URL OUT_DIR [GAP_MS] [TRIES]
//
// Twice: the page as it opens (the skinned meshes), then with `&avatar=sticks` (the stick
// figures). Each time it waits until the page lists >= 2 drawn players, then takes real
// screenshots GAP_MS apart (default 400). For each screenshot it counts, outside the
// HUD panel, the pixels in each player's colour (by hue: the meshes are lit, so the
// brightness varies); for each consecutive pair, the pixels that changed, and those
// that changed where an avatar is (in a player's colour in either shot). The demo's
// walkers stand still for 2.4 s of every 12 s clip, and cross (one can hide the other,
// or loop back out of the view until the camera catches up), so it keeps taking
// screenshots (up to TRIES, default 12) until a pair shows motion with every player
// visible in both shots (at least VISIBLE_PIXELS of its colour: the test's own minimum
// for that avatar). It also reads the names on the page (player list, and the labels
// over the heads).
//
// For the meshes, also (the page otherwise draws its jitter buffer's samples; frozen, it
// draws the newest poses as streamed): (a) with the page frozen on one frame (`posecastViewer.freeze`),
// a screenshot and the page's body pieces on the screen (`posecastViewer.screen`: each
// piece's bone between the streamed joints, with its half-width plus 4 cm in pixels at
// that depth): the pixels of each player's colour outside all of that player's pieces
// are strays, a limb drawn off its joints; (b) on 20 frozen frames, the page's CPU skinning
// of the mesh (`posecastViewer.skin`: rings of the mesh at its joints and halfway along
// each bone, against the streamed joint positions; see viewer/avatar.ts); (b') both
// again with four bones turned away on purpose (`posecastViewer.tamper`), which they
// must notice; (c) the `s` key switches to sticks and back.
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
const tries = Number(triesArg ?? 12);
const MOVED_PIXELS = 400; // avatar pixels that must change between two shots
// Pixels of a player's colour that make it visible in a shot (test_viewer.py's minimums).
const VISIBLE_PIXELS = { mesh: 5000, sticks: 1000, model: 5000 };
const TRACK_S = 5; // the models' hands and feet read back over this span
const BENCH_AVATARS = 16;
const BENCH_FRAMES = 600;
const withParam = (address, param) => `${address}${address.includes("?") ? "&" : "?"}${param}`;

/**
 * Runs in the page: pixel statistics of two PNG screenshots (base64), or of one (`b`
 * absent) with each player's bones on the screen (`bones`: player -> segments `[x0, y0,
 * x1, y1, reach]`, CSS pixels), to count the strays beyond reach.
 */
async function analyse({ a, b, bones }) {
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
  const ia = await decode(a);
  const ib = b === undefined ? ia : await decode(b);
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
  const segments = players.map((p) => bones?.[p.player] ?? []);
  const strays = players.map(() => 0);
  const farthest = players.map(() => 0); // px beyond reach, the worst stray
  /** How far CSS pixel (x, y) lies beyond the reach of the nearest of `segs` (<= 0: within). */
  const beyond = (segs, x, y) => {
    let best = Infinity;
    for (const [x0, y0, x1, y1, reach] of segs) {
      const [dx, dy] = [x1 - x0, y1 - y0];
      const t = Math.max(0, Math.min(1, ((x - x0) * dx + (y - y0) * dy) / Math.max(1e-9, dx * dx + dy * dy)));
      best = Math.min(best, Math.hypot(x - x0 - t * dx, y - y0 - t * dy) - reach);
    }
    return best;
  };
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
      if (oa >= 0 && bones !== undefined) {
        const over = beyond(segments[oa], x / sx, y / sy);
        if (over > 0) {
          strays[oa]++;
          farthest[oa] = Math.max(farthest[oa], over);
        }
      }
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
    players: players.map((p, k) => ({
      ...p,
      pixels_a: pixelsA[k],
      pixels_b: pixelsB[k],
      ...(bones === undefined ? {} : { stray_pixels: strays[k], stray_beyond_px: Math.round(farthest[k]) }),
    })),
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
let stage = "start"; // where it was, for the error line
try {
  const page = browser.pages()[0] ?? (await browser.newPage());
  page.on("console", (m) => logs.push(`${m.type()}: ${m.text()}`));
  page.on("pageerror", (e) => logs.push(`pageerror: ${e.message}`));
  const screenshots = [];
  const save = (png, name) => {
    const path = join(outDir, `viewer-${name}.png`);
    writeFileSync(path, png);
    screenshots.push(path);
  };
  const frames = (n) =>
    page.evaluate(
      (k) => new Promise((done) => {
        const step = () => (k-- > 0 ? requestAnimationFrame(step) : done());
        step();
      }),
      n,
    );

  /** Opens `address`, waits for two drawn players, and measures motion between screenshots. */
  async function motion(address, name, kind = name) {
    stage = `${name}: opening ${address}`;
    await page.goto(address, { waitUntil: "load", timeout: 20_000 });
    await page.waitForFunction(
      () => {
        const v = window.posecastViewer;
        return v && v.frames > 10 && v.players().filter((p) => p.drawn).length >= 2;
      },
      null,
      { timeout: 20_000, polling: 100 },
    );
    stage = `${name}: screenshots`;
    await page.waitForTimeout(700); // let the camera settle on the players
    const shots = [await page.screenshot({ type: "png" })];
    const pairs = [];
    while (shots.length <= tries) {
      await page.waitForTimeout(gapMs);
      shots.push(await page.screenshot({ type: "png" }));
      const [a, b] = shots.slice(-2).map((s) => s.toString("base64"));
      const stats = await page.evaluate(analyse, { a, b });
      pairs.push(stats);
      const visible = stats.players.length >= 2 && stats.players.every(
        (p) => Math.min(p.pixels_a, p.pixels_b) >= VISIBLE_PIXELS[kind],
      );
      if (visible && stats.changed_skeleton_pixels >= MOVED_PIXELS) break;
    }
    shots.slice(-2).forEach((png, i) => save(png, `${name}-${"ab"[i]}`));
    const mode = await page.evaluate(() => window.posecastViewer.mode);
    return { mode, ...pairs.at(-1), pairs: pairs.length };
  }

  // The procedural skinned body (`avatar=mesh`; the page opens on the models).
  const mesh = await motion(withParam(url, "avatar=mesh"), "mesh");

  stage = "mesh: attachment checks";
  /**
   * Freezes the page on a frame where every player's body lies inside the view (a
   * walker that loops back to its start can be off-screen until the camera catches up),
   * and returns that frame's screenshot and each player's pieces on the screen.
   */
  async function frozenFrame() {
    const [w, h] = [1000, 640];
    for (let k = 0; ; k++) {
      await page.evaluate(() => window.posecastViewer.freeze(true));
      await frames(3);
      const screen = await page.evaluate(() => window.posecastViewer.screen());
      const inView = screen.every((p) =>
        p.segments.length > 0 &&
        p.segments.every(([x0, y0, x1, y1]) => [x0, x1].every((x) => x > 0 && x < w) && [y0, y1].every((y) => y > 0 && y < h)),
      );
      if (inView || k >= 40) {
        const png = await page.screenshot({ type: "png" });
        return { png, in_view: inView, bones: Object.fromEntries(screen.map((p) => [p.player, p.segments])) };
      }
      await page.evaluate(() => window.posecastViewer.freeze(false));
      await page.waitForTimeout(150);
    }
  }

  // (a) Strays: one frozen frame, its screenshot and its bones on the screen.
  const { png: still, bones, in_view: stillInView } = await frozenFrame();
  const strays = await page.evaluate(analyse, { a: still.toString("base64"), bones });
  await page.evaluate(() => window.posecastViewer.freeze(false));
  save(still, "mesh-frozen");
  mesh.in_view = stillInView;
  mesh.strays = strays.players.map(({ player, pixels_a, stray_pixels, stray_beyond_px }) => ({
    player,
    pixels: pixels_a,
    stray_pixels,
    stray_beyond_px,
    bones: bones[player]?.length ?? 0,
  }));

  // (b) The skinned mesh against the streamed joints, on 20 frames (each frozen on the
  // newest streamed poses: the jitter buffer's extrapolated samples are not FK-consistent).
  const skin = {};
  for (let k = 0; k < 20; k++) {
    await page.evaluate(() => window.posecastViewer.freeze(true));
    await frames(2);
    const sampled = await page.evaluate(() => window.posecastViewer.skin());
    await page.evaluate(() => window.posecastViewer.freeze(false));
    await frames(1);
    for (const s of sampled) {
      const acc = (skin[s.player] ??= { samples: 0, max_m: 0, mean_m: 0, bone_max_m: 0, worst: "", scale: s.scale });
      acc.samples++;
      acc.mean_m += (s.mean_m - acc.mean_m) / acc.samples;
      acc.bone_max_m = Math.max(acc.bone_max_m, s.bone_max_m);
      if (s.max_m >= acc.max_m) [acc.max_m, acc.worst] = [s.max_m, s.worst];
    }
  }
  mesh.skin = skin;

  // (b') The same checks with four bones turned away from their joints: they must notice.
  // The thighs swing out sideways and the upper arms forward (90 degrees in their own
  // frames): from any side, some of it stands out of the body.
  const h = Math.SQRT1_2;
  const turns = {
    LEFT_THIGH: [0, 0, h, h],
    RIGHT_THIGH: [0, 0, -h, h],
    LEFT_UPPER_ARM: [0, -h, 0, h],
    RIGHT_UPPER_ARM: [0, h, 0, h],
  };
  await page.evaluate((t) => Object.entries(t).forEach(([j, q]) => window.posecastViewer.tamper(j, q)), turns);
  await frames(2);
  const { png: bent, bones: bentBones, in_view: bentInView } = await frozenFrame();
  const bentStrays = await page.evaluate(analyse, { a: bent.toString("base64"), bones: bentBones });
  const bentSkin = await page.evaluate(() => window.posecastViewer.skin());
  await page.evaluate((t) => Object.keys(t).forEach((j) => window.posecastViewer.tamper(j, null)), turns);
  await page.evaluate(() => window.posecastViewer.freeze(false));
  save(bent, "mesh-tampered");
  mesh.tampered = {
    in_view: bentInView,
    strays: bentStrays.players.map(({ player, pixels_a, stray_pixels, stray_beyond_px }) => ({
      player, pixels: pixels_a, stray_pixels, stray_beyond_px,
    })),
    skin: bentSkin,
  };

  // (c) The toggle: the `s` key to sticks and back.
  const shown = () => page.evaluate(() => window.posecastViewer.players().map((p) => p.shown));
  await page.keyboard.press("s");
  await frames(2);
  const toggled = { key_once: await page.evaluate(() => window.posecastViewer.mode), shown_once: await shown() };
  await page.keyboard.press("s");
  await frames(2);
  Object.assign(toggled, { key_twice: await page.evaluate(() => window.posecastViewer.mode), shown_twice: await shown() });
  mesh.toggle = toggled;
  const restOffsets = await page.evaluate(() => window.posecastViewer.restOffsets());

  // The stick figures, by URL parameter.
  const sticks = await motion(withParam(url, "avatar=sticks"), "sticks");

  // The models (the page as it opens), a VRM and a glTF humanoid of other proportions:
  // drawn and moving on screenshots, then their bound skeletons read back each frame
  // for TRACK_S seconds against the poses that drove them.
  const models = {};
  for (const kind of ["vrm", "gltf"]) {
    // `interp=off`: each frame draws the newest pose as streamed, so the bound skeleton
    // is compared with streamed positions (the jitter buffer's samples are not FK-consistent).
    const address = withParam(url, kind === "vrm" ? "interp=off" : `model=${kind}&interp=off`);
    const m = await motion(address, `model-${kind}`, "model");
    stage = `model-${kind}: tracking`;
    m.model = await page.evaluate(() => window.posecastViewer.model);
    m.track = await page.evaluate((s) => window.posecastViewer.track(s), TRACK_S);
    // For the record: the same through the jitter buffer (its samples' own FK disagreement shows).
    await page.evaluate(() => window.posecastViewer.interpolate(true));
    m.track_interpolated = await page.evaluate((s) => window.posecastViewer.track(s), 2);
    models[kind] = m;
  }

  // The binding's cost for BENCH_AVATARS avatars, and its heap: V8's sampling heap
  // profiler (every allocation, those collected since included) over BENCH_FRAMES
  // frames of the page's synchronous benchmark loop; then the same loop copying each
  // pose first (one allocation per avatar per frame), which it must see.
  stage = "benchmark";
  const cdp = await page.context().newCDPSession(page);
  await cdp.send("HeapProfiler.enable");
  const prepared = await page.evaluate((n) => window.posecastViewer.benchPrepare(n), BENCH_AVATARS);
  // Warm up: until V8 has optimised the loop, its interpreter boxes doubles (an
  // allocation now and then in three.js's quaternion-to-Euler sync), gone after ~600
  // frames. The copying run comes last: its other pose shape would deoptimise `update`.
  await page.evaluate((f) => window.posecastViewer.benchRun(f, false), 2 * BENCH_FRAMES);
  // One sampling session, read at marks: starting the profiler costs a one-time
  // allocation (some 6 KB, as V8 re-tiers the code), which the settling run absorbs;
  // then the measured run, then the copying run, each the difference between two marks.
  /** Bytes allocated in the subtrees of the calls named `name` (below a call named `below`). */
  const inside = (node, name, below, seen = below === undefined) => {
    if (seen && node.callFrame.functionName === name) return subtree(node);
    const deeper = seen || node.callFrame.functionName === below;
    return node.children.reduce((sum, c) => sum + inside(c, name, below, deeper), 0);
  };
  const subtree = (node) => node.selfSize + node.children.reduce((sum, c) => sum + subtree(c), 0);
  const frameNames = (node, into = new Set()) => {
    into.add(node.callFrame.functionName);
    node.children.forEach((c) => frameNames(c, into));
    return into;
  };
  const mark = async () => {
    const { profile } = await cdp.send("HeapProfiler.getSamplingProfile");
    // The binding's update path: HumanoidAvatar.update and all it calls, below benchRun;
    // and the whole benchmark loop (its own timing arithmetic and three.js's matrix update too).
    return { update: inside(profile.head, "update", "benchRun"), loop: inside(profile.head, "benchRun"), names: frameNames(profile.head) };
  };
  await cdp.send("HeapProfiler.collectGarbage");
  await cdp.send("HeapProfiler.startSampling", {
    samplingInterval: 32,
    includeObjectsCollectedByMinorGC: true,
    includeObjectsCollectedByMajorGC: true,
  });
  await page.evaluate(() => window.posecastViewer.benchRun(300, false)); // settle
  const m0 = await mark();
  const timing = await page.evaluate((f) => window.posecastViewer.benchRun(f, false), BENCH_FRAMES);
  const m1 = await mark();
  const copying = await page.evaluate((f) => window.posecastViewer.benchRun(f, true), BENCH_FRAMES);
  const m2 = await mark();
  await cdp.send("HeapProfiler.stopSampling");
  const window_ = (a, b) => ({ update_allocated_bytes: b.update - a.update, loop_allocated_bytes: b.loop - a.loop });
  const benchmark = {
    ...prepared,
    settle_update_allocated_bytes: m0.update,
    run: { ...timing, ...window_(m0, m1) },
    allocating: { ...copying, ...window_(m1, m2), found_update_frame: m2.names.has("update") },
  };
  await page.evaluate(() => window.posecastViewer.benchEnd());

  const names = await page.evaluate(() => ({
    list_names: [...document.querySelectorAll("#players .name")].map((e) => e.textContent),
    label_names: [...document.querySelectorAll("#labels .label")]
      .filter((e) => !e.hidden)
      .map((e) => e.textContent),
    status: document.getElementById("status").textContent,
    frames: window.posecastViewer.frames,
  }));
  console.log(JSON.stringify({ mesh, sticks, models, benchmark, rest_offsets: restOffsets, ...names, screenshots, logs }));
} catch (err) {
  console.log(JSON.stringify({ error: `${err} (at ${stage})`, logs }));
  process.exitCode = 1;
} finally {
  await browser.close();
  rmSync(profile, { recursive: true, force: true });
}

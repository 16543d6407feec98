/**
 * One client process of `posecast bench latency --sdk typescript`: TypeScript SDK
 * players (the public API of `src/index.ts`) that stream a walk at 60 Hz, receive
 * their room-mates' poses and show them through the SDK's `Interpolator` in a display
 * loop: what `posecast/offline/evaluation/latency/players.py` does with the Python SDK,
 * for the Python side (`node_players.py`) to read back into the same `WorkerResult`.
 *
 *   node latency-worker.cjs PLAN.json RESULT.json
 *
 * PLAN.json (written by `node_players.py`): the server's URL, each player's token,
 * room, role and first frame time, and a file of its frames: the Python SDK's
 * `WalkSource` sampled in Python (so both SDK modes stream the same motion), float64
 * little-endian, 29 numbers a frame (4 x 3 positions, 4 x 4 xyzw orientations in slot
 * order, the `valid` mask). RESULT.json: what was measured (see {@link Result}).
 *
 * Every time is on the host's CLOCK_MONOTONIC, in seconds: `process.hrtime.bigint()`
 * (libuv's `uv_hrtime`, `clock_gettime(CLOCK_MONOTONIC)` on Linux), the clock Python's
 * `time.monotonic()` reads and the server stamps poses with, so no offset is estimated
 * anywhere. It is each client's `options.clock` too (its pings, its frames' `t`).
 */

import { readFileSync, writeFileSync } from "node:fs";

import WebSocket from "ws";

import {
  connect,
  type FrameInput,
  Interpolator,
  type PosecastClient,
  type PoseSample,
  type TrackerPose,
} from "../src/index.js";
import { type Displayed, DisplayWatch, JumpMeter } from "./display.js";

const FRAME_NUMBERS = 29; // 12 positions, 16 orientations, the valid mask
const SLOTS = ["head", "leftHand", "rightHand", "waist"] as const;
const STALL_S = 0.25; // a sender this far behind starts over instead of catching up (WalkSource's rule)

interface PlayerPlan {
  readonly player: string;
  readonly room: string;
  readonly token: string;
  /** Samples every room-mate's pose each display frame; the joint jumps are its. */
  readonly draws: boolean;
  /** The client time of its first frame (the run's start plus its own phase). */
  readonly start_at: number;
  /** Its frames in the walks file: from frame `first`, `frames` of them (looped). */
  readonly first: number;
  readonly frames: number;
}

interface Plan {
  readonly url: string;
  readonly protocol: 1 | 2;
  readonly walks: string;
  readonly players: readonly PlayerPlan[];
  readonly measure_from: number;
  readonly stop_at: number;
  readonly tail_s: number;
  readonly display_hz: number;
  readonly frame_hz: number;
}

/** What the process measured: `WorkerResult`'s fields (`node_players.py` reads them). */
interface Result {
  started_at: number; // this process's clock when it started (checked against Python's)
  captures: Record<string, [number, number][]>; // player -> [seq, capture time]
  displayed: Displayed[]; // the drawing players' first
  drawn: number;
  waiting: [string, number, number, number][];
  jumps_m: number[];
  members: Record<string, string>;
  welcome: { lookahead_frames?: number; rate_hz?: number; version?: number };
  errors: Record<string, number>;
  failures: string[];
  display_frames: number;
  display_frames_late: number;
  cpu_s: number;
  wall_s: number;
}

/** The host's CLOCK_MONOTONIC, seconds. */
const clock = (): number => Number(process.hrtime.bigint()) / 1e9;
const startedAt = clock();

/** Resolve after `s` seconds; at once (but after pending I/O) when `s <= 0`. */
function sleep(s: number): Promise<void> {
  return new Promise((resolve) => (s > 0 ? setTimeout(resolve, s * 1000) : setImmediate(resolve)));
}

function describe(err: unknown): string {
  return err instanceof Error ? `${err.name}: ${err.message}` : String(err);
}

/** One frame of `walks` as the SDK's `FrameInput` (a slot whose valid bit is clear is left out). */
function frameAt(walks: Float64Array, k: number, t: number): FrameInput {
  const o = k * FRAME_NUMBERS;
  const valid = walks[o + 28]!;
  const input: Record<string, TrackerPose | number> = { t };
  SLOTS.forEach((slot, i) => {
    if ((valid & (1 << i)) === 0) return;
    const p = o + 3 * i;
    const q = o + 12 + 4 * i;
    input[slot] = {
      position: [walks[p]!, walks[p + 1]!, walks[p + 2]!],
      orientation: [walks[q]!, walks[q + 1]!, walks[q + 2]!, walks[q + 3]!],
    };
  });
  return input as FrameInput;
}

/** One player's receiving side: its interpolator and what it showed. */
class Receiver {
  readonly interp = new Interpolator(); // the SDK's defaults: the adaptive render delay
  readonly watch = new DisplayWatch();
  readonly jumps: JumpMeter;
  readonly displayed: Displayed[] = [];
  private readonly samples = new Map<string, PoseSample>();
  private readonly shownT = new Map<string, number>();
  private readonly positions = new Map<string, Float64Array>();

  constructor(
    readonly client: PosecastClient,
    readonly me: string,
    readonly draws: boolean,
    displayHz: number,
  ) {
    this.jumps = new JumpMeter(displayHz);
  }

  /** One display frame, now: every room-mate sampled (`posesAtInto`, the SDK's
   * allocation-free batch). The TypeScript interpolator has no `advance` (the Python
   * SDK's time-only query), so a player that does not draw samples all the same and
   * reads only the shown times. */
  show(record: boolean): void {
    const now = clock();
    // Before the first pong the Python SDK's display_time returns the client time; the
    // TypeScript one throws. Both clocks are the host's, so the client time is right.
    const at = this.client.clock.offsetS === undefined ? now : this.client.clock.displayTime(now);
    this.interp.posesAtInto(at, this.samples);
    this.shownT.clear();
    for (const [player, s] of this.samples) this.shownT.set(player, s.t);
    this.watch.frame(now, this.shownT, this.displayed);
    if (!this.draws) return;
    this.positions.clear();
    for (const [player, s] of this.samples) this.positions.set(player, s.positions);
    this.jumps.frame(now, this.positions, record);
  }
}

/** Replay `p`'s frames from its `start_at` until `plan.stop_at`, as `WalkSource` paces them. */
async function stream(
  client: PosecastClient,
  plan: Plan,
  p: PlayerPlan,
  walks: Float64Array,
  captures: [number, number][],
): Promise<void> {
  await sleep(p.start_at - clock());
  const period = 1 / plan.frame_hz;
  let start = clock();
  for (let k = 0; ; k++) {
    const due = start + k * period;
    const now = clock();
    if (due > now) await sleep(due - now);
    else if (now - due > STALL_S) start = now - k * period; // stalled: do not catch up
    const t = clock(); // the capture time: when the frame is sent
    if (t >= plan.stop_at) return;
    const seq = client.sendFrame(frameAt(walks, p.first + (k % p.frames), t));
    if (seq !== undefined) captures.push([seq, t]);
  }
}

async function read(client: PosecastClient, r: Receiver, out: Result): Promise<void> {
  for await (const ev of client.events()) {
    const now = clock();
    if (ev.type === "pose") {
      if (ev.player === r.me) continue; // its own avatar: a game draws that from its trackers
      r.interp.feed(ev);
      r.watch.received(ev.player, ev.seq, ev.t, now);
      continue;
    }
    r.interp.feed(ev);
    if (ev.type === "presence" && ev.event === "leave") {
      r.watch.forget(ev.player);
      r.jumps.forget(ev.player);
    } else if (ev.type === "error") {
      out.errors[ev.error.code] = (out.errors[ev.error.code] ?? 0) + 1;
    }
  }
}

/** The display loop: every receiver shown once a period until the tail ends; a frame
 * more than a period late is skipped, as a compositor drops frames. */
async function display(receivers: readonly Receiver[], plan: Plan, out: Result): Promise<void> {
  const period = 1 / plan.display_hz;
  const start = clock();
  const end = plan.stop_at + plan.tail_s;
  let cpu0: NodeJS.CpuUsage | undefined;
  for (let k = 0; ; k++) {
    let due = start + k * period;
    await sleep(due - clock()); // always yields, even when behind, so readers and senders run
    const now = clock();
    if (now >= end) return;
    if (now - due > period) {
      k = Math.floor((now - start) / period); // dropped frames: on to the current one
      due = start + k * period;
    }
    const record = plan.measure_from <= now && now < plan.stop_at;
    if (record) {
      if (cpu0 === undefined) {
        cpu0 = process.cpuUsage();
        out.wall_s = now;
      }
      out.display_frames++;
      if (now - due > period / 2) out.display_frames_late++;
    } else if (cpu0 !== undefined && out.cpu_s === 0 && now >= plan.stop_at) {
      const used = process.cpuUsage(cpu0);
      out.cpu_s = (used.user + used.system) / 1e6;
      out.wall_s = now - out.wall_s;
    }
    for (const r of receivers) r.show(record);
  }
}

async function run(plan: Plan, walks: Float64Array, out: Result): Promise<void> {
  const clients: PosecastClient[] = [];
  const receivers: Receiver[] = [];
  let displaying = true;
  const failed = (err: unknown): void => {
    if (displaying) out.failures.push(describe(err)); // a session that ended early
  };
  try {
    const joined = await Promise.all(
      plan.players.map(async (p) => {
        const client = await connect(plan.url, p.token, {
          WebSocket, reconnect: false, protocol: plan.protocol, clock,
        });
        clients.push(client); // closed at the end, whatever happens next
        return { p, client, welcome: await client.join(p.room, p.player) };
      }),
    );
    const work: Promise<void>[] = [];
    for (const { p, client, welcome } of joined) {
      const me = welcome.player;
      out.welcome = { lookahead_frames: welcome.lookahead_frames, rate_hz: welcome.rate_hz, version: client.version };
      out.members[me] = p.room;
      const r = new Receiver(client, me, p.draws, plan.display_hz);
      receivers.push(r);
      const captures: [number, number][] = [];
      out.captures[me] = captures;
      work.push(read(client, r, out).catch(failed));
      work.push(stream(client, plan, p, walks, captures).catch(failed));
    }
    await display(receivers, plan, out);
  } finally {
    displaying = false;
    await Promise.all(clients.map((c) => c.close().catch(() => undefined)));
  }
  for (const r of [...receivers].sort((a, b) => Number(b.draws) - Number(a.draws))) {
    for (const row of r.displayed) out.displayed.push(row);
    if (r.draws) out.drawn += r.displayed.length;
    out.waiting.push(...r.watch.waiting());
    for (const j of r.jumps.jumpsM) out.jumps_m.push(j);
  }
}

async function main(): Promise<void> {
  const [planPath, resultPath] = process.argv.slice(2);
  if (planPath === undefined || resultPath === undefined) {
    throw new Error("usage: node latency-worker.cjs PLAN.json RESULT.json");
  }
  const plan = JSON.parse(readFileSync(planPath, "utf8")) as Plan;
  const bytes = readFileSync(plan.walks); // copied: a Buffer's offset need not be 8-aligned
  const walks = new Float64Array(bytes.buffer.slice(bytes.byteOffset, bytes.byteOffset + bytes.byteLength));
  const out: Result = {
    started_at: startedAt, captures: {}, displayed: [], drawn: 0, waiting: [], jumps_m: [],
    members: {}, welcome: {}, errors: {}, failures: [], display_frames: 0,
    display_frames_late: 0, cpu_s: 0, wall_s: 0,
  };
  await run(plan, walks, out);
  writeFileSync(resultPath, JSON.stringify(out));
}

main().then(
  () => process.exit(0),
  (err: unknown) => {
    process.stderr.write(`latency worker: ${err instanceof Error ? (err.stack ?? describe(err)) : String(err)}\n`);
    process.exit(1);
  },
);

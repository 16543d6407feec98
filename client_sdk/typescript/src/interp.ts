/**
 * Interpolation: a jitter buffer per player, sampled at any display rate. Pure: the
 * caller passes every time, nothing here reads a clock. The same rules as the Python
 * SDK's `posecast_client.interp`, checked by the shared table
 * `proto/vectors/sdk/interp.json`.
 *
 * Poses arrive at uneven moments, but each carries the server time `t` of the tick
 * that made it. A {@link PoseBuffer} keeps a player's recent poses ordered by `t` and
 * shows them a render delay late on the server's timeline, so arrival jitter up to
 * the delay never shows. The delay adapts (`adaptive`, the default): it follows the
 * jitter the buffer measures, the smallest delay at which 99 % of the recent pose
 * intervals interpolate, within `minDelayS` to `maxDelayS`, changing by at most 5 %
 * of real time (`render-delay.ts`, pinned by `proto/vectors/sdk/delay.json`);
 * `adaptive: false` keeps it at `delayS`:
 *
 * ```ts
 * const buffers = new Interpolator();                  // one PoseBuffer per player
 * for await (const ev of client) buffers.feed(ev);     // poses, leaves, welcomes
 * // each rendered frame:
 * const now = client.clock.displayTime(performance.now() / 1000); // throws before a pong
 * for (const [player, shown] of buffers.posesAt(now)) draw(player, shown);
 * ```
 *
 * The query time is the display clock (`ClockSync.displayTime`), not `toServer`: the
 * clock estimate steps by up to tens of ms when its best ping leaves the window, and
 * the display clock slews such steps instead of popping every avatar.
 *
 * At query time `time` the buffer shows `tau = time - delay` ({@link PoseBuffer.delayS}).
 * With `a` the newest pose at or before `tau` and `b` the one after it:
 *
 * 1. **interpolate**: positions lerp and rotations slerp (shortest arc) from a to b.
 * 2. **snap**: b starts a new segment when its pelvis moved more than `teleportM`
 *    from a, when it follows a by more than `gapS`, or when it was pushed as a
 *    `keyframe` and its `seq` is not newer than a's (a new sequence: a rejoin; a
 *    forward seq gap, as at a pose rate below 60 Hz, blends). Until `tau` reaches `b.t`, a is
 *    shown as if it were the newest pose (rule 3); from `b.t` on, b.
 * 3. **extrapolate**: past the newest pose, a moves on at the velocity from its
 *    predecessor for at most `maxExtrapolateS`, then **holds** there.
 * 4. **hold**: before the first pose, and from a pose with no predecessor in its
 *    segment, that pose is shown as it is.
 * 5. **correct smoothly**: {@link PoseBuffer.poseAt} remembers what it showed last.
 *    When poses that arrived since then change that answer (rule 3 guessed through a
 *    burst of lost poses and the late ones say otherwise), the difference is added
 *    back and fades as `exp(-dt / correctionS)`, so a wrong guess costs no step. A
 *    segment start between the two frames, time going back, or a pause longer than
 *    `gapS` shows the new answer at once.
 *
 * Memory: `capacity` poses per player, `maxPlayers` buffers per {@link Interpolator}.
 * Arrays: positions `3 * J` metres, rotations `4 * J` xyzw (unit on the way out).
 *
 * Without allocation: {@link PoseBuffer.poseAtInto} and {@link Interpolator.posesAtInto}
 * write each frame into caller-owned {@link PoseSample}s (their arrays are reused);
 * `poseAt` / `posesAt` copy such a sample into fresh objects.
 */

import type { ClientEvent } from "./events.js";
import { seqDelta } from "./messages.js";
import { type InterpolatedPose, PoseSample, type SampleMode } from "./pose-sample.js";
import { RenderDelay } from "./render-delay.js";
import { slerpInto } from "./slerp.js";

export { type InterpolatedPose, PoseSample, type SampleMode } from "./pose-sample.js";
export { quatSlerp } from "./slerp.js";

/** What a buffer reads from a pose; a decoded `Pose` fits. */
export interface PoseInput {
  readonly player: string;
  readonly seq: number;
  /** Server time of the tick that made it, seconds. */
  readonly t: number;
  readonly positions: ArrayLike<number>;
  readonly rotations?: ArrayLike<number> | undefined;
}

export interface InterpOptions {
  /**
   * The render delay follows the measured arrival jitter (default true; see
   * `render-delay.ts`); false: it stays `delayS`.
   */
  readonly adaptive?: boolean;
  /** The fixed render delay, seconds, and the adaptive one's start (clamped to its bounds). Default 0.1. */
  readonly delayS?: number;
  /** The adaptive delay's lower bound, seconds. Default 0.02 (a bit above a 60 Hz pose interval). */
  readonly minDelayS?: number;
  /** Its upper bound, seconds. Default 0.25. */
  readonly maxDelayS?: number;
  /** The share of recent pose intervals it lets interpolate whole (nearest rank). Default 0.99. */
  readonly delayQuantile?: number;
  /** The recent poses it measures. Default 256 (about 4 s at 60 Hz). */
  readonly delayWindow?: number;
  /** Added to that quantile, seconds. Default 0.002. */
  readonly delayMarginS?: number;
  /** The most it changes per second of query time. Default 0.05 (shown time at 0.95 to 1.05 of real speed). */
  readonly delaySlew?: number;
  /** Longest carry past the newest pose before holding, seconds. Default 0.1. */
  readonly maxExtrapolateS?: number;
  /** A pelvis jump between consecutive poses beyond this snaps, metres. Default 1. */
  readonly teleportM?: number;
  /** Consecutive poses further apart than this snap (and count toward no delay), seconds. Default 0.25. */
  readonly gapS?: number;
  /** Poses kept per player. Default 32 (a 0.5 s delay at 60 Hz). */
  readonly capacity?: number;
  /**
   * Time constant over which a correction fades out, seconds (rule 5). Default 0.05;
   * 0 shows each correction at once.
   */
  readonly correctionS?: number;
}

type Config = Required<InterpOptions>;

const DEFAULTS: Config = {
  adaptive: true,
  delayS: 0.1,
  minDelayS: 0.02,
  maxDelayS: 0.25,
  delayQuantile: 0.99,
  delayWindow: 256,
  delayMarginS: 0.002,
  delaySlew: 0.05,
  maxExtrapolateS: 0.1,
  teleportM: 1.0,
  gapS: 0.25,
  capacity: 32,
  correctionS: 0.05,
};

function config(options: InterpOptions): Config {
  const c: Config = { ...DEFAULTS, ...options };
  const nonNegative = [
    "delayS", "maxExtrapolateS", "correctionS", "minDelayS", "maxDelayS", "delayMarginS", "delaySlew",
  ] as const;
  for (const k of nonNegative) {
    if (!(Number.isFinite(c[k]) && c[k] >= 0)) throw new RangeError(`${k} must be finite and >= 0`);
  }
  for (const k of ["teleportM", "gapS"] as const) {
    if (!(c[k] > 0)) throw new RangeError(`${k} must be > 0`); // Infinity: never snap on it
  }
  if (!(Number.isInteger(c.capacity) && c.capacity >= 2)) {
    throw new RangeError("capacity must be an integer >= 2");
  }
  if (c.minDelayS > c.maxDelayS) throw new RangeError("minDelayS must be <= maxDelayS");
  if (!(c.delayQuantile > 0 && c.delayQuantile <= 1)) throw new RangeError("delayQuantile must be in (0, 1]");
  if (!(Number.isInteger(c.delayWindow) && c.delayWindow >= 1)) {
    throw new RangeError("delayWindow must be an integer >= 1");
  }
  return c;
}

interface Entry {
  t: number;
  seq: number;
  keyframe: boolean;
  positions: Float64Array;
  rotations: Float64Array | undefined;
  seen: boolean; // a query ran since it was pushed (its need is counted)
}

/** `dst` holding a copy of `src`: `dst` itself when the lengths match. */
function fit(dst: Float64Array | undefined, src: ArrayLike<number>): Float64Array {
  if (dst === undefined || dst.length !== src.length) return Float64Array.from(src);
  for (let i = 0; i < src.length; i++) dst[i] = src[i]!;
  return dst;
}

/** The jitter buffer of one player (see the module comment for the rules). */
export class PoseBuffer {
  readonly options: Readonly<Config>;
  player: string | undefined;
  private readonly entries: Entry[] = []; // sorted by t, no two with the same t
  private readonly delay: RenderDelay;
  private unseen = 0; // entries pushed since the last poseAt
  private readonly last = new PoseSample(); // what poseAt showed last, while hasLast
  private hasLast = false;
  private readonly before = new PoseSample(); // rule 5's scratch
  private off = new Float64Array(0); // rule 5's per-joint turns, reused
  private rest = new Float64Array(0); // identities, as many as off

  constructor(options: InterpOptions = {}) {
    this.options = config(options);
    const o = this.options;
    this.delay = new RenderDelay({
      startS: o.delayS, minS: o.minDelayS, maxS: o.maxDelayS, quantile: o.delayQuantile,
      window: o.delayWindow, marginS: o.delayMarginS, slew: o.delaySlew,
    });
  }

  get size(): number {
    return this.entries.length;
  }

  /** Server time of the newest pose kept (undefined while empty). */
  get newestT(): number | undefined {
    return this.entries[this.entries.length - 1]?.t;
  }

  /** The render delay now, seconds: `options.delayS` when not adaptive. */
  get delayS(): number {
    return this.options.adaptive ? this.delay.delayS : this.options.delayS;
  }

  /** The delay the adaptive delay moves toward (undefined before it measured a pose interval, and when not adaptive). */
  get targetDelayS(): number | undefined {
    return this.options.adaptive ? this.delay.targetS : undefined;
  }

  /**
   * The server time the last {@link poseAt} showed (its `tau`); undefined before it
   * showed a pose. A received pose is first on screen at the first frame whose
   * `shownT` reaches its `t`.
   */
  get shownT(): number | undefined {
    return this.hasLast ? this.last.t : undefined;
  }

  /**
   * Keep `pose`; false when it was dropped: a duplicate of a kept `t`, a non-finite
   * `t`, or older than everything kept while the buffer is full. `keyframe`: a resync
   * point (a v2 keyframe); when its `seq` is not newer than its predecessor's (a new
   * sequence) it snaps instead of being blended into. Once full, the oldest pose's
   * arrays are reused for the new one.
   */
  push(pose: PoseInput, keyframe = false): boolean {
    const t = pose.t;
    if (!Number.isFinite(t)) return false;
    const e = this.entries;
    let i = this.lowerBound(t);
    if (e[i]?.t === t) return false;
    if (i === 0 && e.length >= this.options.capacity) return false;
    this.player = pose.player;
    let entry: Entry | undefined;
    if (e.length >= this.options.capacity) {
      entry = e[0]!; // the oldest goes (i >= 1 here): reuse its arrays
      if (!entry.seen) this.unseen--;
      for (let k = 1; k < e.length; k++) e[k - 1] = e[k]!;
      e.length--;
      i--;
    }
    const positions = fit(entry?.positions, pose.positions);
    const rotations = pose.rotations === undefined ? undefined : fit(entry?.rotations, pose.rotations);
    if (entry === undefined) entry = { t, seq: pose.seq, keyframe, positions, rotations, seen: false };
    else {
      entry.t = t;
      entry.seq = pose.seq;
      entry.keyframe = keyframe;
      entry.positions = positions;
      entry.rotations = rotations;
      entry.seen = false;
    }
    e.push(entry);
    for (let k = e.length - 1; k > i; k--) e[k] = e[k - 1]!;
    e[i] = entry;
    this.unseen++;
    return true;
  }

  /** Forget every pose (after a reconnect: the server's clock may have changed). */
  clear(): void {
    this.entries.length = 0;
    this.hasLast = false;
    this.unseen = 0;
    this.delay.reset();
  }

  /**
   * The pose shown at server time `time` (`time - delayS` on the poses' timeline), or
   * undefined before the first pose arrived. Call it once per displayed frame, with
   * times that do not go back: a correction since the last call fades out over
   * `correctionS` (rule 5); adaptive, it also counts the poses pushed since the last
   * call as arrived at `time` and moves the delay. {@link sampleAt} is the same sample
   * without that memory. {@link poseAtInto} is the same without allocating.
   */
  poseAt(time: number): InterpolatedPose | undefined {
    const out = new PoseSample();
    return this.poseAtInto(time, out) ? out.toPose() : undefined;
  }

  /** {@link poseAt} written into `out` (false, `out` untouched: no pose yet). */
  poseAtInto(time: number, out: PoseSample): boolean {
    if (this.options.adaptive) {
      this.observe(time);
      this.delay.advance(time);
    }
    const tau = time - this.delayS;
    const hadLast = this.hasLast;
    this.hasLast = false;
    if (!this.rawInto(tau, out)) return false;
    const last = this.last;
    if (hadLast && this.blends(last.t, tau)) {
      const before = this.before; // what the last frame would show with today's poses
      this.rawInto(last.t, before);
      const k = Math.exp(-(tau - last.t) / this.options.correctionS);
      const pos = out.positions;
      for (let i = 0; i < pos.length; i++) pos[i] = pos[i]! + (last.positions[i]! - before.positions[i]!) * k;
      if (out.hasRotations && last.hasRotations && before.hasRotations) this.fadeTurns(last, before, k, out);
    }
    last.copyFrom(out);
    this.hasLast = true;
    return true;
  }

  /** The pose at server time `time` from the poses kept now: rules 1 to 4, no memory, at the current delay. */
  sampleAt(time: number): InterpolatedPose | undefined {
    const out = new PoseSample();
    return this.rawInto(time - this.delayS, out) ? out.toPose() : undefined;
  }

  /** Each pose pushed since the last query arrived, for the display, at `time` (see render-delay.ts). */
  private observe(time: number): void {
    if (this.unseen === 0) return;
    const gap = this.options.gapS;
    const measures = this.delay.measures(time, gap);
    const e = this.entries;
    for (let k = 0; k < e.length; k++) {
      const entry = e[k]!;
      if (entry.seen) continue;
      entry.seen = true;
      if (measures && k > 0 && entry.t - e[k - 1]!.t <= gap) this.delay.observe(time - e[k - 1]!.t);
    }
    this.unseen = 0;
  }

  /** Rule 5 on rotations: `out[j] = slerp(1, last[j] * conj(before[j]), k) * out[j]`. */
  private fadeTurns(last: PoseSample, before: PoseSample, k: number, out: PoseSample): void {
    const n = out.rotationData.length;
    if (this.off.length !== n) {
      this.off = new Float64Array(n);
      this.rest = new Float64Array(n);
      for (let j = 3; j < n; j += 4) this.rest[j] = 1;
    }
    const a = last.rotationData;
    const b = before.rotationData;
    const off = this.off;
    for (let j = 0; j < n; j += 4) {
      // a * conj(b): the world turn from b to a
      const x1 = a[j]!, y1 = a[j + 1]!, z1 = a[j + 2]!, w1 = a[j + 3]!;
      const x2 = -b[j]!, y2 = -b[j + 1]!, z2 = -b[j + 2]!, w2 = b[j + 3]!;
      off[j] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2;
      off[j + 1] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2;
      off[j + 2] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2;
      off[j + 3] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2;
    }
    slerpInto(this.rest, off, k, off);
    const r = out.rotationData;
    for (let j = 0; j < n; j += 4) {
      const x1 = off[j]!, y1 = off[j + 1]!, z1 = off[j + 2]!, w1 = off[j + 3]!;
      const x2 = r[j]!, y2 = r[j + 1]!, z2 = r[j + 2]!, w2 = r[j + 3]!;
      r[j] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2;
      r[j + 1] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2;
      r[j + 2] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2;
      r[j + 3] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2;
    }
  }

  /** Whether a correction since the frame at `lastTau` fades (rule 5). */
  private blends(lastTau: number, tau: number): boolean {
    const dt = tau - lastTau;
    if (this.options.correctionS === 0 || !(dt > 0 && dt <= this.options.gapS)) return false;
    const hi = this.upperBound(tau);
    for (let k = Math.max(this.upperBound(lastTau), 1); k < hi; k++) {
      if (this.snaps(this.entries[k - 1]!, this.entries[k]!)) return false;
    }
    return true;
  }

  /** Rules 1 to 4 at `tau` on the poses' timeline, into `out`; false while empty. */
  private rawInto(tau: number, out: PoseSample): boolean {
    const first = this.entries[0];
    if (first === undefined) return false;
    const i = this.upperBound(tau) - 1; // a = entries[i]: the newest at or before tau
    if (i < 0) return this.hold(first, tau, out);
    const a = this.entries[i]!;
    const b = this.entries[i + 1];
    const ap = a.positions;
    if (b !== undefined && !this.snaps(a, b)) {
      const u = (tau - a.t) / (b.t - a.t);
      const rot = a.rotations !== undefined && b.rotations !== undefined;
      this.head(out, a, tau, "interpolate", rot);
      for (let k = 0; k < ap.length; k++) out.positions[k] = ap[k]! + (b.positions[k]! - ap[k]!) * u;
      if (rot) slerpInto(a.rotations!, b.rotations!, u, out.rotationData);
      return true;
    }
    // a is the newest pose of its segment: carry it on, then hold.
    const p = i > 0 ? this.entries[i - 1] : undefined;
    const bound = this.options.maxExtrapolateS;
    if (p === undefined || this.snaps(p, a) || bound === 0) return this.hold(a, tau, out);
    const ahead = tau - a.t;
    const s = Math.min(ahead, bound) / (a.t - p.t);
    const rot = a.rotations !== undefined && p.rotations !== undefined;
    this.head(out, a, tau, ahead <= bound ? "extrapolate" : "hold", rot);
    for (let k = 0; k < ap.length; k++) out.positions[k] = ap[k]! + (ap[k]! - p.positions[k]!) * s;
    if (rot) slerpInto(p.rotations!, a.rotations!, 1 + s, out.rotationData);
    return true;
  }

  /** Whether `b` starts a new segment after `a` (rule 2). */
  private snaps(a: Entry, b: Entry): boolean {
    if (b.t - a.t > this.options.gapS) return true;
    if (b.keyframe && seqDelta(b.seq, a.seq) <= 0) return true;
    const ap = a.positions; // joint 0, the pelvis
    const bp = b.positions;
    const dx = bp[0]! - ap[0]!;
    const dy = bp[1]! - ap[1]!;
    const dz = bp[2]! - ap[2]!;
    return Math.sqrt(dx * dx + dy * dy + dz * dz) > this.options.teleportM;
  }

  private hold(a: Entry, tau: number, out: PoseSample): true {
    this.head(out, a, tau, "hold", a.rotations !== undefined);
    out.positions.set(a.positions);
    const q = a.rotations;
    if (q !== undefined) {
      const r = out.rotationData;
      for (let j = 0; j < q.length; j += 4) {
        const n = Math.sqrt(q[j]! * q[j]! + q[j + 1]! * q[j + 1]! + q[j + 2]! * q[j + 2]! + q[j + 3]! * q[j + 3]!);
        for (let k = 0; k < 4; k++) r[j + k] = q[j + k]! / n;
      }
    }
    return true;
  }

  /** `out` shaped like `a` (with rotations: `rot`), its scalars set. */
  private head(out: PoseSample, a: Entry, tau: number, mode: SampleMode, rot: boolean): void {
    out.shape(a.positions.length, rot ? a.rotations!.length : 0);
    out.player = this.player ?? "";
    out.t = tau;
    out.seq = a.seq;
    out.mode = mode;
  }

  /** The first index whose t is >= `t`. */
  private lowerBound(t: number): number {
    let lo = 0;
    let hi = this.entries.length;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (this.entries[mid]!.t < t) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }

  /** The first index whose t is > `t`. */
  private upperBound(t: number): number {
    let lo = 0;
    let hi = this.entries.length;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (this.entries[mid]!.t <= t) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }
}

/** A {@link PoseBuffer} per player, created on a player's first pose. */
export class Interpolator {
  readonly options: InterpOptions;
  /** Buffers kept at most; past it, the player heard from least recently goes. */
  readonly maxPlayers: number;
  private readonly buffers = new Map<string, PoseBuffer>(); // least recent first
  // posesAtInto's state, read by its two callbacks (made once: no closure per frame)
  private frame = 0;
  private frameTime = 0;
  private frameOut: Map<string, PoseSample> | undefined;
  private shown = 0;
  private readonly fill = (buf: PoseBuffer, player: string): void => {
    const out = this.frameOut!;
    let sample = out.get(player);
    if (sample === undefined) {
      sample = new PoseSample();
      out.set(player, sample);
    }
    if (buf.poseAtInto(this.frameTime, sample)) {
      sample.frame = this.frame;
      this.shown++;
    }
  };
  private readonly prune = (sample: PoseSample, player: string, out: Map<string, PoseSample>): void => {
    if (sample.frame !== this.frame) out.delete(player);
  };

  constructor(options: InterpOptions = {}, maxPlayers = 512) {
    config(options); // validate once, here
    if (!(Number.isInteger(maxPlayers) && maxPlayers >= 1)) {
      throw new RangeError("maxPlayers must be an integer >= 1");
    }
    this.options = options;
    this.maxPlayers = maxPlayers;
  }

  get players(): string[] {
    return [...this.buffers.keys()];
  }

  buffer(player: string): PoseBuffer | undefined {
    return this.buffers.get(player);
  }

  /** Route `pose` to its player's buffer (see {@link PoseBuffer.push}). */
  push(pose: PoseInput, keyframe = false): boolean {
    let buf = this.buffers.get(pose.player);
    if (buf === undefined) buf = new PoseBuffer(this.options);
    this.buffers.delete(pose.player); // re-insert: most recent last
    this.buffers.set(pose.player, buf);
    while (this.buffers.size > this.maxPlayers) {
      this.buffers.delete(this.buffers.keys().next().value!);
    }
    return buf.push(pose, keyframe);
  }

  /**
   * Take any client event: a pose is pushed (a v2 keyframe as a resync point), a
   * `leave` forgets its player, a `welcome` (a join or a resume, maybe on another
   * server clock) clears every buffer.
   */
  feed(ev: ClientEvent): void {
    if (ev.type === "pose") this.push(ev, ev.keyframe === true);
    else if (ev.type === "presence" && ev.event === "leave") this.forget(ev.player);
    else if (ev.type === "welcome") this.clear();
  }

  forget(player: string): void {
    this.buffers.delete(player);
  }

  clear(): void {
    this.buffers.clear();
  }

  /** `player`'s pose shown at server time `time`, or undefined if unknown. */
  poseAt(player: string, time: number): InterpolatedPose | undefined {
    return this.buffers.get(player)?.poseAt(time);
  }

  /** Every known player's pose shown at server time `time`. */
  posesAt(time: number): Map<string, InterpolatedPose> {
    const out = new Map<string, InterpolatedPose>();
    for (const [player, buf] of this.buffers) {
      const shown = buf.poseAt(time);
      if (shown !== undefined) out.set(player, shown);
    }
    return out;
  }

  /**
   * {@link posesAt} without allocating once warm: every known player's pose at `time`
   * written into `out`'s {@link PoseSample} for that player (one is made the first
   * time a player shows); players no longer shown leave `out`. Keep `out` from frame
   * to frame. Returns the number of players shown.
   */
  posesAtInto(time: number, out: Map<string, PoseSample>): number {
    this.frame++;
    this.frameTime = time;
    this.frameOut = out;
    this.shown = 0;
    this.buffers.forEach(this.fill);
    if (out.size > this.shown) out.forEach(this.prune);
    this.frameOut = undefined;
    return this.shown;
  }
}

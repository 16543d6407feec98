/**
 * Interpolation: a jitter buffer per player, sampled at any display rate. Pure: the
 * caller passes every time, nothing here reads a clock. The same rules as the Python
 * SDK's `posecast_client.interp`, checked by the shared table
 * `proto/vectors/sdk/interp.json`.
 *
 * Poses arrive at uneven moments, but each carries the server time `t` of the tick
 * that made it. A {@link PoseBuffer} keeps a player's recent poses ordered by `t` and
 * shows them a fixed `delayS` late on the server's timeline, so arrival jitter up to
 * the delay never shows:
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
 * At query time `time` the buffer shows `tau = time - delayS`. With `a` the newest
 * pose at or before `tau` and `b` the one after it:
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
 */

import type { ClientEvent } from "./events.js";
import { seqDelta } from "./messages.js";

export type SampleMode = "interpolate" | "extrapolate" | "hold";

/** What a buffer reads from a pose; a decoded `Pose` fits. */
export interface PoseInput {
  readonly player: string;
  readonly seq: number;
  /** Server time of the tick that made it, seconds. */
  readonly t: number;
  readonly positions: ArrayLike<number>;
  readonly rotations?: ArrayLike<number> | undefined;
}

/** One player's pose as shown at `t` (the query time minus the delay). */
export interface InterpolatedPose {
  readonly player: string;
  /** Server time shown, seconds. */
  readonly t: number;
  /** `seq` of the received pose at or before `t` (the first one while holding it). */
  readonly seq: number;
  /** World positions, metres, joint order (length 3 * J). */
  readonly positions: Float64Array;
  /** World rotations, unit xyzw (length 4 * J); absent when the poses had none. */
  readonly rotations?: Float64Array;
  readonly mode: SampleMode;
}

export interface InterpOptions {
  /** Render delay, seconds behind the query time. Default 0.1. */
  readonly delayS?: number;
  /** Longest carry past the newest pose before holding, seconds. Default 0.1. */
  readonly maxExtrapolateS?: number;
  /** A pelvis jump between consecutive poses beyond this snaps, metres. Default 1. */
  readonly teleportM?: number;
  /** Consecutive poses further apart than this snap, seconds. Default 0.25. */
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
  delayS: 0.1,
  maxExtrapolateS: 0.1,
  teleportM: 1.0,
  gapS: 0.25,
  capacity: 32,
  correctionS: 0.05,
};

function config(options: InterpOptions): Config {
  const c: Config = { ...DEFAULTS, ...options };
  for (const k of ["delayS", "maxExtrapolateS", "correctionS"] as const) {
    if (!(Number.isFinite(c[k]) && c[k] >= 0)) throw new RangeError(`${k} must be finite and >= 0`);
  }
  for (const k of ["teleportM", "gapS"] as const) {
    if (!(c[k] > 0)) throw new RangeError(`${k} must be > 0`); // Infinity: never snap on it
  }
  if (!(Number.isInteger(c.capacity) && c.capacity >= 2)) {
    throw new RangeError("capacity must be an integer >= 2");
  }
  return c;
}

interface Entry {
  readonly t: number;
  readonly seq: number;
  readonly keyframe: boolean;
  readonly positions: Float64Array;
  readonly rotations: Float64Array | undefined;
}

function unit(q: Float64Array): Float64Array {
  const out = new Float64Array(q.length);
  for (let j = 0; j < q.length; j += 4) {
    const n = Math.hypot(q[j]!, q[j + 1]!, q[j + 2]!, q[j + 3]!);
    for (let k = 0; k < 4; k++) out[j + k] = q[j + k]! / n;
  }
  return out;
}

function identities(n: number): Float64Array {
  const out = new Float64Array(4 * n);
  for (let j = 3; j < out.length; j += 4) out[j] = 1;
  return out;
}

/** Hamilton products `a[j] * b[j]` of every xyzw quaternion (apply b, then a). */
function quatMul(a: ArrayLike<number>, b: ArrayLike<number>): Float64Array {
  const out = new Float64Array(a.length);
  for (let j = 0; j < a.length; j += 4) {
    const [x1, y1, z1, w1] = [a[j]!, a[j + 1]!, a[j + 2]!, a[j + 3]!];
    const [x2, y2, z2, w2] = [b[j]!, b[j + 1]!, b[j + 2]!, b[j + 3]!];
    out[j] = w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2;
    out[j + 1] = w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2;
    out[j + 2] = w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2;
    out[j + 3] = w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2;
  }
  return out;
}

/** `a[j] * conj(b[j])`: the world turn from unit `b` to `a`. */
function quatMulConj(a: ArrayLike<number>, b: ArrayLike<number>): Float64Array {
  const conj = Float64Array.from(b);
  for (let j = 0; j < conj.length; j += 4) {
    conj[j] = -conj[j]!;
    conj[j + 1] = -conj[j + 1]!;
    conj[j + 2] = -conj[j + 2]!;
  }
  return quatMul(a, conj);
}

/**
 * Spherical interpolation of every xyzw quaternion in `q0` and `q1` (length 4 * J) on
 * the shorter arc; `u` outside [0, 1] extrapolates along the same great circle.
 * Inputs need not be unit.
 */
export function quatSlerp(q0: ArrayLike<number>, q1: ArrayLike<number>, u: number): Float64Array {
  const out = new Float64Array(q0.length);
  for (let j = 0; j < q0.length; j += 4) {
    const n0 = Math.hypot(q0[j]!, q0[j + 1]!, q0[j + 2]!, q0[j + 3]!);
    const n1 = Math.hypot(q1[j]!, q1[j + 1]!, q1[j + 2]!, q1[j + 3]!);
    let dot = 0;
    for (let k = 0; k < 4; k++) dot += (q0[j + k]! / n0) * (q1[j + k]! / n1);
    const sign = dot < 0 ? -1 : 1; // the same rotation, on q0's hemisphere
    const omega = Math.acos(Math.min(Math.abs(dot), 1));
    const sin = Math.sin(omega);
    let w0 = 1 - u;
    let w1 = u;
    if (sin >= 1e-6) {
      // Nearly equal rotations keep the lerp weights: the sines would cancel badly.
      w0 = Math.sin((1 - u) * omega) / sin;
      w1 = Math.sin(u * omega) / sin;
    }
    let norm = 0;
    for (let k = 0; k < 4; k++) {
      const v = (w0 * q0[j + k]!) / n0 + (sign * w1 * q1[j + k]!) / n1;
      out[j + k] = v;
      norm += v * v;
    }
    norm = Math.sqrt(norm);
    for (let k = 0; k < 4; k++) out[j + k] = out[j + k]! / norm;
  }
  return out;
}

/** The jitter buffer of one player (see the module comment for the rules). */
export class PoseBuffer {
  readonly options: Readonly<Config>;
  player: string | undefined;
  private readonly entries: Entry[] = []; // sorted by t, no two with the same t
  private last: InterpolatedPose | undefined; // what poseAt showed last

  constructor(options: InterpOptions = {}) {
    this.options = config(options);
  }

  get size(): number {
    return this.entries.length;
  }

  /** Server time of the newest pose kept (undefined while empty). */
  get newestT(): number | undefined {
    return this.entries[this.entries.length - 1]?.t;
  }

  /**
   * Keep `pose`; false when it was dropped: a duplicate of a kept `t`, a non-finite
   * `t`, or older than everything kept while the buffer is full. `keyframe`: a resync
   * point (a v2 keyframe); when its `seq` is not newer than its predecessor's (a new
   * sequence) it snaps instead of being blended into.
   */
  push(pose: PoseInput, keyframe = false): boolean {
    const t = pose.t;
    if (!Number.isFinite(t)) return false;
    const i = this.lowerBound(t);
    if (this.entries[i]?.t === t) return false;
    if (i === 0 && this.entries.length >= this.options.capacity) return false;
    this.player = pose.player;
    this.entries.splice(i, 0, {
      t,
      seq: pose.seq,
      keyframe,
      positions: Float64Array.from(pose.positions),
      rotations: pose.rotations === undefined ? undefined : Float64Array.from(pose.rotations),
    });
    if (this.entries.length > this.options.capacity) this.entries.shift();
    return true;
  }

  /** Forget every pose (after a reconnect: the server's clock may have changed). */
  clear(): void {
    this.entries.length = 0;
    this.last = undefined;
  }

  /**
   * The pose shown at server time `time` (`time - delayS` on the poses' timeline), or
   * undefined before the first pose arrived. Call it once per displayed frame, with
   * times that do not go back: a correction since the last call fades out over
   * `correctionS` (rule 5). {@link sampleAt} is the same sample without that memory.
   */
  poseAt(time: number): InterpolatedPose | undefined {
    const tau = time - this.options.delayS;
    const raw = this.raw(tau);
    const last = this.last;
    this.last = undefined;
    if (raw === undefined) return undefined;
    let shown = raw;
    if (last !== undefined && this.blends(last.t, tau)) {
      const before = this.raw(last.t)!; // what the last frame would show with today's poses
      const k = Math.exp(-(tau - last.t) / this.options.correctionS);
      const positions = raw.positions.map((v, i) => v + (last.positions[i]! - before.positions[i]!) * k);
      let rotations = raw.rotations;
      if (rotations && last.rotations && before.rotations) {
        const off = quatMulConj(last.rotations, before.rotations); // per joint, world delta
        rotations = quatMul(quatSlerp(identities(off.length / 4), off, k), rotations);
      }
      shown = this.sample(raw.seq, tau, positions, raw.mode, rotations);
    }
    this.last = shown;
    return shown;
  }

  /** The pose at server time `time` from the poses kept now: rules 1 to 4, no memory. */
  sampleAt(time: number): InterpolatedPose | undefined {
    return this.raw(time - this.options.delayS);
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

  /** Rules 1 to 4 at `tau` on the poses' timeline. */
  private raw(tau: number): InterpolatedPose | undefined {
    const first = this.entries[0];
    if (first === undefined) return undefined;
    const i = this.upperBound(tau) - 1; // a = entries[i]: the newest at or before tau
    if (i < 0) return this.hold(first, tau);
    const a = this.entries[i]!;
    const b = this.entries[i + 1];
    if (b !== undefined && !this.snaps(a, b)) {
      const u = (tau - a.t) / (b.t - a.t);
      const pos = a.positions.map((v, k) => v + (b.positions[k]! - v) * u);
      const rot =
        a.rotations && b.rotations ? quatSlerp(a.rotations, b.rotations, u) : undefined;
      return this.sample(a.seq, tau, pos, "interpolate", rot);
    }
    // a is the newest pose of its segment: carry it on, then hold.
    const p = i > 0 ? this.entries[i - 1] : undefined;
    const bound = this.options.maxExtrapolateS;
    if (p === undefined || this.snaps(p, a) || bound === 0) return this.hold(a, tau);
    const ahead = tau - a.t;
    const s = Math.min(ahead, bound) / (a.t - p.t);
    const pos = a.positions.map((v, k) => v + (v - p.positions[k]!) * s);
    const rot = a.rotations && p.rotations ? quatSlerp(p.rotations, a.rotations, 1 + s) : undefined;
    return this.sample(a.seq, tau, pos, ahead <= bound ? "extrapolate" : "hold", rot);
  }

  /** Whether `b` starts a new segment after `a` (rule 2). */
  private snaps(a: Entry, b: Entry): boolean {
    if (b.t - a.t > this.options.gapS) return true;
    if (b.keyframe && seqDelta(b.seq, a.seq) <= 0) return true;
    const [ax, ay, az] = a.positions; // joint 0, the pelvis
    const [bx, by, bz] = b.positions;
    return Math.hypot(bx! - ax!, by! - ay!, bz! - az!) > this.options.teleportM;
  }

  private hold(a: Entry, tau: number): InterpolatedPose {
    const rot = a.rotations ? unit(a.rotations) : undefined;
    return this.sample(a.seq, tau, Float64Array.from(a.positions), "hold", rot);
  }

  private sample(
    seq: number,
    tau: number,
    positions: Float64Array,
    mode: SampleMode,
    rotations: Float64Array | undefined,
  ): InterpolatedPose {
    const base = { player: this.player ?? "", t: tau, seq, positions, mode };
    return rotations === undefined ? base : { ...base, rotations };
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
}

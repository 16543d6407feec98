/**
 * The adaptive render delay of a jitter buffer. Pure: times go in, a delay comes out.
 * The same rules as the Python SDK's `posecast_client.render_delay`, pinned by
 * `proto/vectors/sdk/delay.json`.
 *
 * A buffer shows `tau = time - delay`. For a pose `b` whose predecessor on the
 * server's timeline is `a`, every frame with `tau` in `[a.t, b.t)` needs `b`, so b's
 * **need** is `seen_b - a.t`: the smallest delay at which every frame between a and b
 * interpolates (it folds in the pose interval, a lost pose before b, and b's
 * lateness). `seen_b` is the first query time at or after b was pushed: the arrival
 * the display experiences, on the display clock. Poses first seen at a query more
 * than `gapS` after the previous one, at the first query, or at an earlier time than
 * one already queried count no need (they may have waited for the display).
 *
 * The needs of the last `window` poses are kept in arrival order and, beside them,
 * sorted (one insertion and one removal per pose, no allocation), and the delay aims
 * at `clamp(needs[ceil(quantile * n) - 1] + marginS, minS, maxS)` (nearest rank). It
 * moves toward it by at most `slew` times the query time that passed, so the shown
 * time runs at `1 - slew` to `1 + slew` of real speed and never goes back or jumps.
 */

/** The nearest-rank `quantile` of the first `n` (> 0) ascending values of `sorted`. */
export function nearestRank(sorted: ArrayLike<number>, n: number, quantile: number): number {
  return sorted[Math.min(n - 1, Math.max(0, Math.ceil(quantile * n) - 1))]!;
}

export interface RenderDelayOptions {
  /** The delay before the first need, seconds (clamped to the bounds). */
  readonly startS: number;
  readonly minS: number;
  readonly maxS: number;
  readonly quantile: number;
  /** Needs kept: the last `window` poses. */
  readonly window: number;
  readonly marginS: number;
  /** The largest change of the delay per second of query time. */
  readonly slew: number;
}

/** One buffer's render delay (see the module comment). */
export class RenderDelay {
  readonly startS: number;
  /** The delay now, seconds. */
  delayS: number;
  private readonly ring: Float64Array; // needs in arrival order; `next` is the oldest when full
  private readonly sorted: Float64Array; // the same needs, ascending, in [0, count)
  private count = 0;
  private next = 0;
  private time = 0; // the latest query time, while hasTime
  private hasTime = false;
  private target = Number.NaN; // the target (NaN: no need yet); numbers only, so V8 boxes none

  constructor(private readonly o: RenderDelayOptions) {
    this.startS = Math.min(Math.max(o.startS, o.minS), o.maxS);
    this.delayS = this.startS;
    this.ring = new Float64Array(o.window);
    this.sorted = new Float64Array(o.window);
  }

  /** Needs kept now. */
  get samples(): number {
    return this.count;
  }

  /** The delay aimed at (undefined before the first need). */
  get targetS(): number | undefined {
    return this.count === 0 ? undefined : this.target;
  }

  /** Whether poses first seen at query `time` tell their arrival (false before any query). */
  measures(time: number, gapS: number): boolean {
    return this.hasTime && time - this.time >= 0 && time - this.time <= gapS;
  }

  /** Keep one pose's need, forgetting the oldest beyond `window`. */
  observe(needS: number): void {
    const s = this.sorted;
    let n = this.count;
    if (n === this.o.window) {
      const i = this.lowerBound(this.ring[this.next]!, n);
      s.copyWithin(i, i + 1, n);
      n--;
    } else {
      this.count++;
    }
    this.ring[this.next] = needS;
    this.next = (this.next + 1) % this.o.window;
    const i = this.upperBound(needS, n);
    s.copyWithin(i + 1, i, n);
    s[i] = needS;
    const q = nearestRank(s, this.count, this.o.quantile);
    this.target = Math.min(Math.max(q + this.o.marginS, this.o.minS), this.o.maxS);
  }

  /** Move the delay ({@link delayS}) toward the target for the query time `time`. */
  advance(time: number): void {
    const target = this.target;
    if (this.hasTime && time > this.time && this.count > 0) {
      const step = this.o.slew * (time - this.time);
      if (Math.abs(target - this.delayS) <= step) this.delayS = target;
      else this.delayS += target > this.delayS ? step : -step;
    }
    if (!this.hasTime || time > this.time) {
      this.time = time;
      this.hasTime = true;
    }
  }

  /** Forget every need and go back to the start delay. */
  reset(): void {
    this.count = 0;
    this.next = 0;
    this.delayS = this.startS;
    this.hasTime = false;
    this.target = Number.NaN;
  }

  private lowerBound(v: number, n: number): number {
    let lo = 0;
    let hi = n;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (this.sorted[mid]! < v) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }

  private upperBound(v: number, n: number): number {
    let lo = 0;
    let hi = n;
    while (lo < hi) {
      const mid = (lo + hi) >> 1;
      if (this.sorted[mid]! <= v) lo = mid + 1;
      else hi = mid;
    }
    return lo;
  }
}

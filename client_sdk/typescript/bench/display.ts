/**
 * When a received pose is first on screen, and how far joints jump between display
 * frames: the TypeScript twin of `posecast.offline.evaluation.latency.display`, for the
 * Node client processes of `posecast bench latency --sdk typescript` (pure: the caller
 * passes every time; nothing here reads a clock).
 *
 * A pose with server time `t` received at client time `r` is **displayed** at the first
 * display frame at or after `r` whose shown time (the `t` of the `InterpolatedPose` the
 * receiver's interpolator returned for its sender) reaches `t`. A pose that arrives
 * after the shown time has passed it is displayed at the first frame after its arrival.
 * `test/bench-display.test.ts` runs the cases of the Python module's tests.
 */

/** One pose of `sender` (source frame `seq`, server time `t`), received at client time
 * `received`, first displayed at client time `shown`; the tuple the Python side reads. */
export type Displayed = readonly [sender: string, seq: number, t: number, received: number, shown: number];

interface Waiting {
  readonly t: number;
  readonly seq: number;
  readonly received: number;
}

/** The first index of `list` (sorted by `t`) whose `t` is greater than `t`. */
function upperBound(list: readonly Waiting[], t: number): number {
  let lo = 0;
  let hi = list.length;
  while (lo < hi) {
    const mid = (lo + hi) >> 1;
    if (list[mid]!.t <= t) lo = mid + 1;
    else hi = mid;
  }
  return lo;
}

/** The poses one receiver got and has not displayed yet, per sender (sorted by `t`). */
export class DisplayWatch {
  private readonly pending = new Map<string, Waiting[]>();

  /** A pose of `sender` with server time `t` arrived at client time `at`. */
  received(sender: string, seq: number, t: number, at: number): void {
    let list = this.pending.get(sender);
    if (list === undefined) {
      list = [];
      this.pending.set(sender, list);
    }
    list.splice(upperBound(list, t), 0, { t, seq, received: at }); // after equal times, as insort
  }

  /** The display frame at client time `now` showed each sender at server time
   * `shownT.get(sender)`: the poses it displays for the first time (appended to `out`). */
  frame(now: number, shownT: ReadonlyMap<string, number>, out: Displayed[]): void {
    for (const [sender, t] of shownT) {
      const list = this.pending.get(sender);
      if (list === undefined || list.length === 0) continue;
      const k = upperBound(list, t);
      for (let i = 0; i < k; i++) {
        const w = list[i]!;
        out.push([sender, w.seq, w.t, w.received, now]);
      }
      list.splice(0, k);
    }
  }

  /** `sender` left: its waiting poses will never be displayed. */
  forget(sender: string): void {
    this.pending.delete(sender);
  }

  /** `[sender, seq, t, received]` of every pose not displayed yet. */
  waiting(): [string, number, number, number][] {
    const rows: [string, number, number, number][] = [];
    for (const [sender, list] of this.pending) {
      for (const w of list) rows.push([sender, w.seq, w.t, w.received]);
    }
    return rows;
  }
}

/**
 * The largest joint displacement between consecutive display frames, per sender, at a
 * nominal display rate: a frame more than one period after the last has its
 * displacement scaled to one period (`d * period / dt`), so a display loop held up by
 * the machine does not count as the stream's jump.
 */
export class JumpMeter {
  readonly jumpsM: number[] = [];
  private readonly last = new Map<string, { at: number; positions: Float64Array }>();
  private readonly periodS: number;

  constructor(displayHz: number) {
    this.periodS = 1 / displayHz;
  }

  /** The frame at client time `now` showed each sender's joints at `positions` (xyz per
   * joint, metres; copied); `record = false` keeps the frame without its jumps. */
  frame(now: number, positions: ReadonlyMap<string, ArrayLike<number>>, record = true): void {
    for (const [sender, pos] of positions) {
      let last = this.last.get(sender);
      const fresh = last === undefined || last.positions.length !== pos.length;
      if (last !== undefined && !fresh && record && now - last.at > 0) {
        const p = last.positions;
        let d2 = 0;
        for (let j = 0; j + 2 < pos.length; j += 3) {
          const dx = pos[j]! - p[j]!;
          const dy = pos[j + 1]! - p[j + 1]!;
          const dz = pos[j + 2]! - p[j + 2]!;
          d2 = Math.max(d2, dx * dx + dy * dy + dz * dz);
        }
        this.jumpsM.push(Math.sqrt(d2) * Math.min(1, this.periodS / (now - last.at)));
      }
      if (last === undefined || fresh) {
        last = { at: now, positions: new Float64Array(pos.length) };
        this.last.set(sender, last);
      }
      last.at = now;
      last.positions.set(pos);
    }
  }

  forget(sender: string): void {
    this.last.delete(sender);
  }
}

/**
 * Clock sync from `ping`/`pong` (pure: times in, an offset out).
 *
 * With `t0` the client time a ping left, `t1`/`t2` the server times it arrived and
 * the pong left, and `t3` the client time the pong arrived (`proto/README.md`):
 *
 * ```text
 * offset = ((t1 - t0) + (t2 - t3)) / 2      server_time ~ client_time + offset
 * rtt    = (t3 - t0) - (t2 - t1)
 * ```
 *
 * A sample's error is at most rtt / 2, so the estimate is the sample with the
 * smallest rtt among the last `window` (default 8); one slow round trip (a GC pause,
 * a busy Wi-Fi channel) then never moves it.
 *
 * That estimate steps whenever the best sample leaves the window or a better one
 * arrives (by up to tens of ms on a jittery link), and rendering at `toServer(now)`
 * would move every remote avatar by velocity x step. {@link ClockSync.displayTime} is
 * a display clock that slews instead, as NTP's clock discipline does: its offset moves
 * toward the estimate by at most `slewRate` seconds per second of client time (0.5 %:
 * 5 ms a second, so the shown time always advances, at 0.995 to 1.005 of real speed)
 * and steps to it only when the two differ by more than `snapS` (0.1 s: the first
 * pong, a reconnect after `reset()`, a restarted server). The same rules as the Python
 * SDK's `posecast_client.clock`, checked by `proto/vectors/sdk/clock.json`.
 */

export interface ClockSample {
  /** Server time minus client time, seconds. */
  readonly offsetS: number;
  /** Round trip minus the server's own hold time, seconds. */
  readonly rttS: number;
  /** Client time the pong arrived, seconds. */
  readonly atS: number;
}

export class ClockSync {
  private readonly samples: ClockSample[] = [];
  /** The display clock's offset, and the latest client time it was given. */
  private shownS: number | undefined;
  private shownAt: number | undefined;

  /**
   * @param window how many recent samples compete for the best (smallest rtt).
   * @param slewRate how fast {@link displayTime}'s offset may move toward the estimate,
   *   seconds per second of client time (0.005).
   * @param snapS a difference beyond which the display offset steps to the estimate
   *   at once (0.1 s).
   */
  constructor(
    readonly window = 8,
    readonly slewRate = 0.005,
    readonly snapS = 0.1,
  ) {
    if (!(window >= 1)) throw new RangeError("window must be >= 1");
    // At 1 or more the shown time could stop.
    if (!(slewRate >= 0 && slewRate < 1)) throw new RangeError("slewRate must be in [0, 1)");
    if (!(snapS >= 0)) throw new RangeError("snapS must be >= 0");
  }

  /**
   * Add one ping/pong exchange; returns that exchange's own sample, or undefined
   * (and keeps nothing) when the times are absurd: a negative round trip or a pong
   * before its ping (a clock jumped, or a pong for a ping of another connection).
   */
  add(t0: number, t1: number, t2: number, t3: number): ClockSample | undefined {
    const rttS = t3 - t0 - (t2 - t1);
    if (!(rttS >= 0) || !(t3 >= t0)) return undefined;
    const sample = { offsetS: (t1 - t0 + (t2 - t3)) / 2, rttS, atS: t3 };
    this.samples.push(sample);
    if (this.samples.length > this.window) this.samples.shift();
    return sample;
  }

  /** The best recent sample (smallest rtt), or undefined before the first pong. */
  get best(): ClockSample | undefined {
    let best: ClockSample | undefined;
    for (const s of this.samples) if (best === undefined || s.rttS < best.rttS) best = s;
    return best;
  }

  /** Estimated server time minus client time, seconds (undefined before a pong). */
  get offsetS(): number | undefined {
    return this.best?.offsetS;
  }

  /** Round-trip time of the best sample, seconds (undefined before a pong). */
  get rttS(): number | undefined {
    return this.best?.rttS;
  }

  /** The server time at client time `clientS` (seconds). Throws before the first pong. */
  toServer(clientS: number): number {
    return clientS + this.requireOffset();
  }

  /** The client time at server time `serverS`, e.g. of `pose.t`. Throws before a pong. */
  toClient(serverS: number): number {
    return serverS - this.requireOffset();
  }

  /**
   * The server time to render at client time `clientS` (seconds): the display clock.
   *
   * `clientS` plus an offset that follows {@link offsetS} without jumping: it moves
   * toward the estimate by at most `slewRate` times the client time since the last
   * call, and steps to it when the two differ by more than `snapS` (and on the first
   * call with an estimate, after a pong or a `reset()`). Between two calls `dt` apart
   * the result so advances by between `(1 - slewRate) * dt` and `(1 + slewRate) * dt`.
   * Sample the interpolator here, not at {@link toServer}, whose steps move each
   * avatar by velocity x step.
   *
   * Pass non-decreasing client times (one monotonic clock). An earlier time slews
   * nothing (a snap still applies): it is shown with the current display offset, so
   * the result goes back as far as the time did, and the next slew is counted from the
   * latest time given. Throws before the first pong, as {@link toServer} does.
   */
  displayTime(clientS: number): number {
    const estimate = this.requireOffset();
    let shown = this.shownS;
    const last = this.shownAt;
    if (shown === undefined || last === undefined || Math.abs(estimate - shown) > this.snapS) {
      shown = estimate; // the first frame, a reset, or a difference too big to slew
    } else if (clientS > last) {
      const step = this.slewRate * (clientS - last);
      shown += Math.min(Math.max(estimate - shown, -step), step);
    }
    this.shownS = shown;
    this.shownAt = last === undefined ? clientS : Math.max(last, clientS);
    return clientS + shown;
  }

  /** The display clock's offset as of the last {@link displayTime} (undefined before it
   * ran with an estimate, and after `reset()`). */
  get displayOffsetS(): number | undefined {
    return this.shownS;
  }

  /** Forget every sample (a new connection may reach a new server process), and the
   * display clock's offset: the next {@link displayTime} after a pong starts on the new
   * estimate. */
  reset(): void {
    this.samples.length = 0;
    this.shownS = undefined;
    this.shownAt = undefined;
  }

  private requireOffset(): number {
    const offset = this.offsetS;
    if (offset === undefined) throw new Error("no clock sample yet (no pong received)");
    return offset;
  }
}

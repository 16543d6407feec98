// Clock sync from ping/pong (NTP-style). Pure: the caller passes every time.
//
// For one exchange, with t0 the client time the ping left, t1/t2 the server times it
// arrived/the pong left, and t3 the client time the pong arrived:
//   offset = ((t1 - t0) + (t2 - t3)) / 2      server_time ~ client_time + offset
//   rtt    = (t3 - t0) - (t2 - t1)
// Of the last few samples the one with the smallest rtt is trusted (its offset is
// wrong by at most rtt / 2).
//
// That estimate steps whenever the best sample leaves the window or a better one
// arrives (by up to tens of ms on a jittery link), and rendering at ToServer(now) would
// move every remote avatar by velocity x step. DisplayTime is a display clock that
// slews instead, as NTP's clock discipline does: its offset moves toward the estimate
// by at most SlewRate seconds per second of client time (0.5 %: 5 ms a second, so the
// shown time always advances, at 0.995 to 1.005 of real speed) and steps to it only
// when the two differ by more than SnapS (0.1 s: the first pong, a reconnect after
// Reset(), a restarted server). The same rules as the Python SDK's
// posecast_client.clock, checked by proto/vectors/sdk/clock.json.

using System;
using System.Collections.Generic;

namespace Posecast.Client
{
    public struct ClockSample
    {
        public double OffsetS;  // server minus client time
        public double RttS;     // round trip without the server's own time
        public double AtS;      // client time of the sample (t3)
    }

    public sealed class ClockSync
    {
        private readonly Queue<ClockSample> _samples = new Queue<ClockSample>();
        private double? _shownS;   // the display clock's offset
        private double? _shownAt;  // the latest client time DisplayTime was given
        /// <summary>How many recent samples the estimate picks from (8).</summary>
        public readonly int Window;
        /// <summary>How fast DisplayTime's offset may move toward the estimate, seconds per second of client time (0.005).</summary>
        public readonly double SlewRate;
        /// <summary>A difference beyond which the display offset steps to the estimate at once (0.1 s).</summary>
        public readonly double SnapS;

        public ClockSync(int window = 8, double slewRate = 0.005, double snapS = 0.1)
        {
            // At a slew rate of 1 or more the shown time could stop.
            if (!(slewRate >= 0 && slewRate < 1)) throw new ArgumentException("slewRate must be in [0, 1)");
            if (!(snapS >= 0)) throw new ArgumentException("snapS must be >= 0");
            Window = window; SlewRate = slewRate; SnapS = snapS;
        }

        /// <summary>Record one exchange; false when the times are absurd (a clock jumped).</summary>
        public bool Add(double t0, double t1, double t2, double t3)
        {
            double rtt = (t3 - t0) - (t2 - t1);
            if (rtt < 0 || t3 < t0) return false;
            _samples.Enqueue(new ClockSample { OffsetS = ((t1 - t0) + (t2 - t3)) / 2.0, RttS = rtt, AtS = t3 });
            while (_samples.Count > Window) _samples.Dequeue();
            return true;
        }

        /// <summary>Forget every sample (after a reconnect the server may be another process), and the
        /// display clock's offset: the next DisplayTime after a pong starts on the new estimate.</summary>
        public void Reset() { _samples.Clear(); _shownS = null; _shownAt = null; }

        /// <summary>The recent sample with the smallest rtt, or null before the first pong.</summary>
        public ClockSample? Best
        {
            get
            {
                ClockSample? best = null;
                foreach (var s in _samples) if (best == null || s.RttS < best.Value.RttS) best = s;
                return best;
            }
        }

        /// <summary>Server time minus client time, seconds (null until a pong arrived).</summary>
        public double? OffsetS { get { var b = Best; return b == null ? (double?)null : b.Value.OffsetS; } }
        public double? RttS { get { var b = Best; return b == null ? (double?)null : b.Value.RttS; } }

        /// <summary>A client time on the server's clock (unchanged before the first pong).</summary>
        public double ToServer(double clientT) { return clientT + (OffsetS ?? 0.0); }
        /// <summary>A server time (pose T, welcome T) on the client's clock.</summary>
        public double ToClient(double serverT) { return serverT - (OffsetS ?? 0.0); }

        /// <summary>
        /// The server time to render at client time clientT: the display clock. clientT plus an
        /// offset that follows OffsetS without jumping: it moves toward the estimate by at most
        /// SlewRate times the client time since the last call, and steps to it when the two differ
        /// by more than SnapS (and on the first call with an estimate, after a pong or a Reset).
        /// Between two calls dt apart the result so advances by between (1 - SlewRate) * dt and
        /// (1 + SlewRate) * dt. Sample the interpolator here, not at ToServer, whose steps move
        /// each avatar by velocity x step.
        /// Pass non-decreasing client times (one monotonic clock). An earlier time slews nothing
        /// (a snap still applies): it is shown with the current display offset, so the result goes
        /// back as far as the time did, and the next slew is counted from the latest time given.
        /// Before the first pong it returns clientT, as ToServer does.
        /// </summary>
        public double DisplayTime(double clientT)
        {
            double? est = OffsetS;
            if (est == null) return clientT;
            double estimate = est.Value;
            if (_shownS == null || _shownAt == null || Math.Abs(estimate - _shownS.Value) > SnapS)
            {
                _shownS = estimate;  // the first frame, a reset, or a difference too big to slew
            }
            else if (clientT > _shownAt.Value)
            {
                double step = SlewRate * (clientT - _shownAt.Value);
                _shownS = _shownS.Value + Math.Min(Math.Max(estimate - _shownS.Value, -step), step);
            }
            _shownAt = _shownAt == null ? clientT : Math.Max(_shownAt.Value, clientT);
            return clientT + _shownS.Value;
        }

        /// <summary>The display clock's offset as of the last DisplayTime (null before it ran with
        /// an estimate, and after Reset).</summary>
        public double? DisplayOffsetS { get { return _shownS; } }
    }
}

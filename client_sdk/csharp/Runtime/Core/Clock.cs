// Clock sync from ping/pong (NTP-style). Pure: the caller passes every time.
//
// For one exchange, with t0 the client time the ping left, t1/t2 the server times it
// arrived/the pong left, and t3 the client time the pong arrived:
//   offset = ((t1 - t0) + (t2 - t3)) / 2      server_time ~ client_time + offset
//   rtt    = (t3 - t0) - (t2 - t1)
// Of the last few samples the one with the smallest rtt is trusted (its offset is
// wrong by at most rtt / 2).

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
        /// <summary>How many recent samples the estimate picks from (8).</summary>
        public readonly int Window;

        public ClockSync(int window = 8) { Window = window; }

        /// <summary>Record one exchange; false when the times are absurd (a clock jumped).</summary>
        public bool Add(double t0, double t1, double t2, double t3)
        {
            double rtt = (t3 - t0) - (t2 - t1);
            if (rtt < 0 || t3 < t0) return false;
            _samples.Enqueue(new ClockSample { OffsetS = ((t1 - t0) + (t2 - t3)) / 2.0, RttS = rtt, AtS = t3 });
            while (_samples.Count > Window) _samples.Dequeue();
            return true;
        }

        /// <summary>Forget every sample (after a reconnect the server may be another process).</summary>
        public void Reset() { _samples.Clear(); }

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
    }
}

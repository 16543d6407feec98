// The adaptive render delay of a jitter buffer. Pure: times go in, a delay comes out.
// The same rules as the Python SDK's posecast_client.render_delay and the TypeScript
// SDK's render-delay.ts, pinned by proto/vectors/sdk/delay.json.
//
// A buffer shows tau = time - delay. For a pose b whose predecessor on the server's
// timeline is a, every frame with tau in [a.t, b.t) needs b, so b's need is
// seen_b - a.t: the smallest delay at which every frame between a and b interpolates
// (the pose interval, a lost pose before b and b's lateness, all in one). seen_b is the
// first query time at or after b was pushed: the arrival the display experiences.
// Poses first seen at a query more than GapS after the previous one, at the first
// query, or at an earlier time than one already queried count no need.
//
// The needs of the last Window poses are kept in arrival order and, beside them,
// sorted (one insertion and one removal per pose, no allocation); the delay aims at
// clamp(needs[ceil(Quantile * n) - 1] + MarginS, MinS, MaxS) (nearest rank) and moves
// toward it by at most Slew times the query time that passed, so the shown time runs
// at 1 - Slew to 1 + Slew of real speed and never goes back or jumps.

using System;

namespace Posecast.Client
{
    /// <summary>One buffer's render delay (see the file comment).</summary>
    public sealed class RenderDelay
    {
        public readonly double StartS, MinS, MaxS, Quantile, MarginS, Slew;
        public readonly int Window;
        /// <summary>The delay now, seconds.</summary>
        public double DelayS { get; private set; }

        private readonly double[] _ring;   // needs in arrival order; _next is the oldest when full
        private readonly double[] _sorted; // the same needs, ascending, in [0, _count)
        private int _count, _next;
        private double _time;
        private bool _hasTime;             // a query time was seen

        public RenderDelay(double startS, double minS, double maxS, double quantile, int window, double marginS, double slew)
        {
            StartS = Math.Min(Math.Max(startS, minS), maxS);
            MinS = minS; MaxS = maxS; Quantile = quantile; Window = window; MarginS = marginS; Slew = slew;
            _ring = new double[window];
            _sorted = new double[window];
            DelayS = StartS;
        }

        /// <summary>The nearest-rank quantile of the first n (> 0) ascending values.</summary>
        public static double NearestRank(double[] sorted, int n, double quantile)
        {
            return sorted[Math.Min(n - 1, Math.Max(0, (int)Math.Ceiling(quantile * n) - 1))];
        }

        /// <summary>Needs kept now.</summary>
        public int Samples { get { return _count; } }

        /// <summary>The delay aimed at (null before the first need).</summary>
        public double? TargetS
        {
            get
            {
                if (_count == 0) return null;
                return Math.Min(Math.Max(NearestRank(_sorted, _count, Quantile) + MarginS, MinS), MaxS);
            }
        }

        /// <summary>Whether poses first seen at query time `time` tell their arrival.</summary>
        public bool Measures(double time, double gapS)
        {
            return _hasTime && time - _time >= 0.0 && time - _time <= gapS;
        }

        /// <summary>Keep one pose's need, forgetting the oldest beyond Window.</summary>
        public void Observe(double needS)
        {
            int n = _count;
            if (n == Window)
            {
                int i = Bound(_ring[_next], n, false);
                Array.Copy(_sorted, i + 1, _sorted, i, n - i - 1);
                n--;
            }
            else _count++;
            _ring[_next] = needS;
            _next = (_next + 1) % Window;
            int at = Bound(needS, n, true);
            Array.Copy(_sorted, at, _sorted, at + 1, n - at);
            _sorted[at] = needS;
        }

        /// <summary>Move the delay toward the target for query time `time`; the delay.</summary>
        public double Advance(double time)
        {
            if (_hasTime && time > _time && _count > 0)
            {
                double target = TargetS.Value;
                double step = Slew * (time - _time);
                if (Math.Abs(target - DelayS) <= step) DelayS = target;
                else DelayS += target > DelayS ? step : -step;
            }
            if (!_hasTime || time > _time) { _time = time; _hasTime = true; }
            return DelayS;
        }

        /// <summary>Forget every need and go back to the start delay.</summary>
        public void Reset() { _count = 0; _next = 0; DelayS = StartS; _hasTime = false; }

        // The first index in [0, n) whose value is > v (right) or >= v (left).
        private int Bound(double v, int n, bool right)
        {
            int lo = 0, hi = n;
            while (lo < hi)
            {
                int mid = (lo + hi) / 2;
                if (right ? _sorted[mid] <= v : _sorted[mid] < v) lo = mid + 1; else hi = mid;
            }
            return lo;
        }
    }
}

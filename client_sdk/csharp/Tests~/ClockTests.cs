// ClockSync: the spec's offset, and the display clock on the shared table
// proto/vectors/sdk/clock.json (the Python SDK writes it; TypeScript runs it too).

using System;
using System.Collections.Generic;

namespace Posecast.Client.Tests
{
    public static class ClockTests
    {
        public static void Register()
        {
            var table = T.Load("proto", "vectors", "sdk", "clock.json");
            double tol = table["tolerance"].D;
            foreach (var c in table["cases"].Items)
            {
                T.Run("clock/" + c["name"].S, () =>
                {
                    var cfg = c["config"];
                    T.Equal(3, cfg.Count, "every knob is named");
                    var clock = new ClockSync((int)cfg["window"].L, cfg["slew_rate"].D, cfg["snap_s"].D);
                    int k = 0;
                    foreach (var step in c["steps"].Items)
                    {
                        k++;
                        if (step.Has("reset")) { clock.Reset(); continue; }
                        if (step.Has("add"))
                        {
                            var t = step["add"].Doubles();
                            T.True(clock.Add(t[0], t[1], t[2], t[3]), "step " + k + " accepted");
                            T.Near(step["offset_s"].D, clock.OffsetS.Value, tol, "step " + k + " offset");
                            continue;
                        }
                        double at = step["display"].D;
                        // null: before the first pong, where DisplayTime returns the client time (as ToServer does).
                        double want = step["expect"].IsNull ? at : step["expect"].D;
                        T.Near(want, clock.DisplayTime(at), tol, "step " + k + " (" + step["rule"].S + ")");
                    }
                });
            }
            T.Run("clock: the table's first config is the SDK's defaults", () =>
            {
                var cfg = table["cases"][0]["config"];
                var d = new ClockSync();
                T.True(cfg["window"].L == d.Window && cfg["slew_rate"].D == d.SlewRate && cfg["snap_s"].D == d.SnapS, "defaults");
            });
            T.Run("clock: a -28 ms step of the estimate is slewed at 0.5 %, never backwards", () =>
            {
                var clock = new ClockSync();
                clock.Add(1.0, 51.03, 51.0302, 1.0322);   // offset 50 + 14 ms (rtt 32 ms)
                var shown = new List<double> { clock.DisplayTime(2.0) };
                clock.Add(2.0, 52.001, 52.0012, 2.0302);  // better (rtt 30 ms): 50 - 14 ms
                for (int i = 1; i <= 900; i++) shown.Add(clock.DisplayTime(2.0 + i / 90.0));
                for (int i = 1; i < shown.Count; i++)
                {
                    double step = shown[i] - shown[i - 1];
                    T.True(step >= 0.995 / 90 - 1e-9 && step <= 1.0 / 90 + 1e-9, "frame " + i + ": " + step);
                }
                T.Near(clock.ToServer(12.0), shown[900], 1e-12, "converged 5.6 s later");
                T.Near(clock.OffsetS.Value, clock.DisplayOffsetS.Value, 0.0, "display offset");
            });
            T.Run("clock: before a pong DisplayTime is the client time; Reset forgets; bad options are refused", () =>
            {
                var clock = new ClockSync();
                T.Equal(3.0, clock.DisplayTime(3.0), "before a pong");
                clock.Add(4.0, 254.01, 254.01, 4.02);
                T.Equal(clock.ToServer(4.5), clock.DisplayTime(4.5), "the first pong snaps");
                clock.Reset();
                T.True(clock.DisplayOffsetS == null, "reset");
                T.Equal(5.0, clock.DisplayTime(5.0), "after a reset");
                T.Throws<ArgumentException>(() => new ClockSync(8, -0.1), "negative slew");
                T.Throws<ArgumentException>(() => new ClockSync(8, 1.0), "slew 1");
                T.Throws<ArgumentException>(() => new ClockSync(8, 0.005, -1.0), "negative snap");
            });
        }
    }
}

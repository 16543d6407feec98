// The adaptive render delay on the shared table proto/vectors/sdk/delay.json (written
// from the Python SDK; TypeScript replays it too), RenderDelay's sorted window, and
// sampling without garbage: 16 players x 600 frames allocate nothing once warm.

using System;
using System.Collections.Generic;

namespace Posecast.Client.Tests
{
    public static class DelayTests
    {
        public static void Register()
        {
            var table = T.Load("proto", "vectors", "sdk", "delay.json");
            double tol = table["tolerance"].D;
            foreach (var c in table["cases"].Items)
            {
                T.Run("delay/" + c["name"].S, () =>
                {
                    var buf = new PoseBuffer(InterpTests.ConfigOf(c["config"]));
                    var into = new InterpolatedPose();
                    int k = 0;
                    foreach (var step in c["steps"].Items)
                    {
                        k++;
                        if (step.Has("push"))
                        {
                            long seq = step["push"][0].L;
                            double t = step["push"][1].D;
                            buf.Push(new PlayerPose { Player = "p", Seq = seq, T = t, Positions = new[] { new Vec3(t - 100.0, 1, 0) } }, false);
                            continue;
                        }
                        bool shown = buf.PoseAt(step["query"].D, into);
                        var want = step["expect"];
                        if (want.IsNull) { T.True(!shown, "step " + k + ": nothing yet"); continue; }
                        T.True(shown, "step " + k + " shows a pose");
                        T.Equal(want["mode"].S, into.Mode.ToString().ToLowerInvariant(), "step " + k + " mode");
                        T.Near(want["t"].D, into.T, tol, "step " + k + " t");
                        T.True(buf.ShownT == into.T, "step " + k + " ShownT");
                        T.Near(want["delay_s"].D, buf.DelayS, tol, "step " + k + " delay");
                        if (want["target_s"].IsNull) T.True(buf.TargetDelayS == null, "step " + k + " no target");
                        else T.Near(want["target_s"].D, buf.TargetDelayS.Value, tol, "step " + k + " target");
                    }
                });
            }
            T.Run("delay: the table's first config is the SDK's defaults", () =>
            {
                var cfg = InterpTests.ConfigOf(table["cases"][0]["config"]);
                var d = InterpConfig.Default;
                T.True(cfg.Adaptive == d.Adaptive && cfg.DelayS == d.DelayS && cfg.MinDelayS == d.MinDelayS && cfg.MaxDelayS == d.MaxDelayS
                       && cfg.DelayQuantile == d.DelayQuantile && cfg.DelayWindow == d.DelayWindow && cfg.DelayMarginS == d.DelayMarginS
                       && cfg.DelaySlew == d.DelaySlew, "defaults");
            });
            T.Run("delay: the window keeps the last needs sorted; slew, bounds, reset", () =>
            {
                var rng = new Random(15);
                var pool = new double[20];
                for (int i = 0; i < pool.Length; i++) pool[i] = Math.Round(rng.NextDouble() * 0.1, 3);
                var rd = new RenderDelay(0.1, 0.0, 10.0, 0.9, 16, 0.0, 1.0);
                var needs = new List<double>();
                for (int i = 0; i < 300; i++)
                {
                    double v = pool[rng.Next(pool.Length)]; // repeats too
                    rd.Observe(v);
                    needs.Add(v);
                    var last = needs.GetRange(Math.Max(0, needs.Count - 16), Math.Min(16, needs.Count)).ToArray();
                    Array.Sort(last);
                    T.True(rd.TargetS == RenderDelay.NearestRank(last, last.Length, 0.9), "target " + i);
                }
                var s = new RenderDelay(0.1, 0.02, 0.25, 1.0, 4, 0.0, 0.05);
                T.True(!s.Measures(10.0, 0.25) && s.Advance(10.0) == 0.1, "first query");
                T.True(s.Measures(10.1, 0.25) && !s.Measures(10.5, 0.25) && !s.Measures(9.9, 0.25), "measures");
                s.Observe(0.03);
                T.Near(0.05, s.Advance(11.0), 1e-12, "1 s at 5 %");
                T.Near(0.05, s.Advance(10.5), 1e-12, "an earlier time moves nothing");
                T.True(s.Advance(11.5) == 0.03, "reached exactly");
                s.Observe(1.0);
                T.True(s.TargetS == 0.25, "bounded");
                s.Reset();
                T.True(s.DelayS == 0.1 && s.TargetS == null && s.Samples == 0, "reset");
                T.True(new PoseBuffer(new InterpConfig(delayS: 0.5)).DelayS == 0.25, "start clamped");
                T.True(new PoseBuffer(new InterpConfig(delayS: 0.5, adaptive: false)).DelayS == 0.5, "fixed");
            });
            T.Run("interp: 16 players x 600 frames at 90 Hz allocate nothing once warm (PosesAt into, Push)", () =>
            {
                const int players = 16, frames = 600, warm = 120;
                var names = new string[players];
                for (int p = 0; p < players; p++) names[p] = "p" + p;
                // Every pose made up front: what a decoder hands over is not the buffer's garbage.
                int poses = frames * 60 / 90 + 10;
                var made = new PlayerPose[players, poses];
                for (int p = 0; p < players; p++)
                    for (int k = 0; k < poses; k++)
                    {
                        double t = 1000.0 + k / 60.0;
                        var pos = new Vec3[19];
                        var rot = new Quat[19];
                        for (int j = 0; j < 19; j++)
                        {
                            pos[j] = new Vec3(t + 0.01 * j, 1.0 + 0.1 * Math.Sin(3 * t + j), p);
                            rot[j] = Quat.FromRotationVector(0.2 * Math.Sin(2 * t + j), t, 0.1 * j);
                        }
                        made[p, k] = new PlayerPose { Player = names[p], Seq = k, T = t, Positions = pos, Rotations = rot };
                    }
                var ip = new Interpolator();
                var into = new Dictionary<string, InterpolatedPose>();
                int next = 0;
                long before = 0;
                int interpolated = 0, sampled = 0;
                for (int f = 0; f < frames; f++)
                {
                    if (f == warm) before = GC.GetAllocatedBytesForCurrentThread();
                    double now = 1000.05 + f / 90.0;
                    // 5 ms late, and every 7th pose held back to the next one (jitter, bursts).
                    while (next < poses && 1000.0 + next / 60.0 + (next % 7 == 3 ? 0.03 : 0.005) <= now)
                    {
                        for (int p = 0; p < players; p++) ip.Push(made[p, next]);
                        next++;
                    }
                    int shown = ip.PosesAt(now, into);
                    if (shown != players) T.Equal(players, shown, "frame " + f + " players shown"); // no string made per frame
                    if (f >= warm)
                        foreach (var kv in into) { sampled++; if (kv.Value.Mode == InterpMode.Interpolate) interpolated++; }
                }
                long allocated = GC.GetAllocatedBytesForCurrentThread() - before;
                T.Equal(0L, allocated, "bytes allocated over frames " + warm + ".." + frames);
                T.True(interpolated >= 0.99 * sampled, "99 % of the samples interpolate: " + interpolated + " of " + sampled);
                var b = ip.Buffer("p3");
                T.True(b.ShownT.HasValue && b.DelayS < 0.1, "shown time and an adapted delay");
            });
            T.Run("interp: PosesAt(time, into) matches PosesAt(time) and drops players that left", () =>
            {
                var a = new Interpolator();
                var b = new Interpolator();
                var into = new Dictionary<string, InterpolatedPose>();
                for (int f = 0; f < 200; f++)
                {
                    double now = 10.0 + f / 90.0;
                    for (int k = (int)Math.Floor((now - 10.0 - 1 / 90.0) * 60) + 1; k <= (int)Math.Floor((now - 10.0) * 60); k++)
                        foreach (var name in new[] { "ada", "bo" })
                        {
                            double t = 10.0 + k / 60.0;
                            var pose = new PlayerPose { Player = name, Seq = k, T = t, Positions = new[] { new Vec3(t, 1, 0), new Vec3(0, t, 0) },
                                                        Rotations = new[] { Quat.FromRotationVector(0, t, 0), Quat.FromRotationVector(t, 0, 0) } };
                            a.Push(pose);
                            b.Push(pose);
                        }
                    var want = a.PosesAt(now);
                    T.Equal(want.Count, b.PosesAt(now, into), "count " + f);
                    foreach (var kv in want)
                    {
                        var got = into[kv.Key];
                        T.True(got.T == kv.Value.T && got.Seq == kv.Value.Seq && got.Mode == kv.Value.Mode, "scalars " + f);
                        for (int j = 0; j < 2; j++)
                        {
                            T.Near(kv.Value.Positions[j], got.Positions[j], 0, "position " + f);
                            T.NearRot(kv.Value.Rotations[j], got.Rotations[j], 0, "rotation " + f);
                        }
                    }
                }
                b.Forget("bo");
                b.PosesAt(20.0, into);
                T.Equal("ada", string.Join(",", into.Keys), "bo left");
            });
        }
    }
}

// The jitter buffer on the shared table proto/vectors/sdk/interp.json, the engine
// conventions on conventions.json, and FK on the reference skeleton.

using System;
using System.Collections.Generic;

namespace Posecast.Client.Tests
{
    public static class InterpTests
    {
        private static PlayerPose ToPose(Json p)
        {
            var pos = new List<Vec3>();
            foreach (var r in p["positions"].Items) { var d = r.Doubles(); pos.Add(new Vec3(d[0], d[1], d[2])); }
            Quat[] rot = null;
            if (!p["rotations"].IsNull)
            {
                var l = new List<Quat>();
                foreach (var r in p["rotations"].Items) { var d = r.Doubles(); l.Add(new Quat(d[0], d[1], d[2], d[3])); }
                rot = l.ToArray();
            }
            return new PlayerPose { Player = "p", Seq = p["seq"].L, T = p["t"].D, Positions = pos.ToArray(), Rotations = rot };
        }

        /// <summary>A shared table's config (Python names); every knob must be named.</summary>
        public static InterpConfig ConfigOf(Json cfg)
        {
            T.Equal(13, cfg.Count, "every knob is named");
            return new InterpConfig(cfg["delay_s"].D, cfg["max_extrapolate_s"].D, cfg["teleport_m"].D,
                                    cfg["gap_s"].D, (int)cfg["capacity"].L, cfg["correction_s"].D,
                                    cfg["adaptive"].Bool, cfg["min_delay_s"].D, cfg["max_delay_s"].D,
                                    cfg["delay_quantile"].D, (int)cfg["delay_window"].L, cfg["delay_margin_s"].D,
                                    cfg["delay_slew"].D);
        }

        public static void Register()
        {
            var table = T.Load("proto", "vectors", "sdk", "interp.json");
            double tolPos = table["tolerance"]["position_m"].D, tolRot = table["tolerance"]["rotation"].D;
            var modes = new HashSet<InterpMode>();
            foreach (var c in table["cases"].Items)
            {
                T.Run("interp/" + c["name"].S, () =>
                {
                    var buf = new PoseBuffer(ConfigOf(c["config"]));
                    int k = 0;
                    foreach (var step in c["steps"].Items)
                    {
                        k++;
                        if (step.Has("push"))
                        {
                            T.Equal(step["accepted"].Bool, buf.Push(ToPose(step["push"]), step["push"]["keyframe"].Bool), "step " + k + " accepted");
                            continue;
                        }
                        var shown = buf.PoseAt(step["query"].D);
                        var want = step["expect"];
                        if (want.IsNull) { T.True(shown == null, "step " + k + ": nothing yet"); continue; }
                        T.True(shown != null, "step " + k + " shows a pose");
                        T.Equal(want["mode"].S, shown.Mode.ToString().ToLowerInvariant(), "step " + k + " mode");
                        T.Equal(want["seq"].L, shown.Seq, "step " + k + " seq");
                        T.Equal("p", shown.Player, "player");
                        T.Near(want["t"].D, shown.T, 1e-12, "step " + k + " t");
                        modes.Add(shown.Mode);
                        for (int j = 0; j < shown.Positions.Length; j++)
                        {
                            var p = want["positions"][j].Doubles();
                            T.Near(new Vec3(p[0], p[1], p[2]), shown.Positions[j], tolPos, "step " + k + " position " + j);
                        }
                        if (want["rotations"].IsNull) { T.True(shown.Rotations == null, "step " + k + " has no rotations"); continue; }
                        for (int j = 0; j < shown.Rotations.Length; j++)
                        {
                            var q = want["rotations"][j].Doubles();
                            T.NearRot(new Quat(q[0], q[1], q[2], q[3]), shown.Rotations[j], tolRot, "step " + k + " rotation " + j);
                        }
                    }
                });
            }
            T.Run("interp: the table exercises interpolate, extrapolate and hold", () => T.Equal(3, modes.Count, "modes"));
            T.Run("interp: the table's first config is the SDK's defaults at a fixed delay", () =>
            {
                var cfg = table["cases"][0]["config"];
                var d = InterpConfig.Default;
                T.True(cfg["delay_s"].D == d.DelayS && cfg["max_extrapolate_s"].D == d.MaxExtrapolateS && cfg["teleport_m"].D == d.TeleportM
                       && cfg["gap_s"].D == d.GapS && cfg["capacity"].L == d.Capacity && cfg["correction_s"].D == d.CorrectionS, "defaults");
                T.True(!cfg["adaptive"].Bool && d.Adaptive, "the rules are pinned at a fixed delay; the default adapts");
            });
            T.Run("interp: bad configs are refused", () =>
            {
                T.Throws<ArgumentException>(() => new InterpConfig(delayS: -1), "negative delay");
                T.Throws<ArgumentException>(() => new InterpConfig(capacity: 1), "capacity 1");
                T.Throws<ArgumentException>(() => new InterpConfig(gapS: 0), "gap 0");
                T.Throws<ArgumentException>(() => new InterpConfig(minDelayS: 0.3), "min above max");
                T.Throws<ArgumentException>(() => new InterpConfig(maxDelayS: double.PositiveInfinity), "infinite max");
                T.Throws<ArgumentException>(() => new InterpConfig(delayQuantile: 0), "quantile 0");
                T.Throws<ArgumentException>(() => new InterpConfig(delayWindow: 0), "window 0");
                T.Throws<ArgumentException>(() => new InterpConfig(delaySlew: -0.05), "negative slew");
            });
            T.Run("interp: the Interpolator routes by player, forgets on leave, clears on welcome, caps players", () =>
            {
                var ip = new Interpolator(maxPlayers: 2);
                var pose = new PlayerPose { Player = "a", Seq = 1, T = 1.0, Positions = new Vec3[19], Rotations = null };
                ip.Push(pose);
                ip.Push(new PlayerPose { Player = "b", Seq = 1, T = 1.0, Positions = new Vec3[19] });
                ip.Push(new PlayerPose { Player = "c", Seq = 1, T = 1.0, Positions = new Vec3[19] });
                T.Equal("b,c", string.Join(",", ip.Players), "the least recent went first");
                ip.Feed(new ClientEvent { Kind = EventKind.Presence, Presence = new Presence { Event = "leave", Player = "b" } });
                T.Equal("c", string.Join(",", ip.Players), "leave");
                T.True(ip.PoseAt("c", 5.0) != null && ip.PoseAt("zz", 5.0) == null, "pose at");
                ip.Feed(new ClientEvent { Kind = EventKind.Welcome, Welcome = new Welcome() });
                T.Equal("", string.Join(",", ip.Players), "welcome clears");
            });
            T.Run("slerp: constant rate on the short arc, q and -q alike", () =>
            {
                var q0 = Quat.FromRotationVector(0.1, 0.2, 0.3);
                var q1 = Quat.FromRotationVector(1.0, -0.5, 0.7);
                double whole = Quat.Angle(q0, q1);
                foreach (var u in new[] { 0.0, 0.25, 0.5, 1.0, 1.2 })
                {
                    T.Near(whole * u, Quat.Angle(q0, Quat.Slerp(q0, q1, u)), 1e-9, "angle at " + u);
                    T.NearRot(Quat.Slerp(q0, q1, u), Quat.Slerp(q0, q1.Negated, u), 1e-12, "hemisphere at " + u);
                }
            });

            var conv = T.Load("proto", "vectors", "sdk", "conventions.json");
            double tp = conv["tolerance"]["position"].D, tr = conv["tolerance"]["rotation"].D;
            foreach (var c in conv["cases"].Items)
            {
                T.Run("conventions/" + c["name"].S, () =>
                {
                    var e = Conventions.Parse(c["engine"].S);
                    for (int j = 0; j < c["positions"].Count; j++)
                    {
                        var p = c["positions"][j].Doubles();
                        var w = c["expect_positions"][j].Doubles();
                        var got = Conventions.PosToEngine(new Vec3(p[0], p[1], p[2]), e);
                        T.Near(new Vec3(w[0], w[1], w[2]), got, tp, "position " + j);
                        T.Near(new Vec3(p[0], p[1], p[2]), Conventions.EngineToPos(got, e), 1e-12, "position back " + j);
                    }
                    for (int j = 0; j < c["rotations"].Count; j++)
                    {
                        var q = c["rotations"][j].Doubles();
                        var w = c["expect_rotations"][j].Doubles();
                        var got = Conventions.QuatToEngine(new Quat(q[0], q[1], q[2], q[3]), e);
                        T.NearRot(new Quat(w[0], w[1], w[2], w[3]), got, tr, "rotation " + j);
                        T.NearRot(new Quat(q[0], q[1], q[2], q[3]), Conventions.EngineToQuat(got, e), 1e-12, "rotation back " + j);
                    }
                });
            }
            T.Run("conventions: head to XR view", () =>
            {
                foreach (var c in conv["head2xrview"].Items)
                {
                    var h = c["head"].Doubles(); var v = c["view"].Doubles();
                    T.NearRot(new Quat(v[0], v[1], v[2], v[3]), Conventions.HeadToXrView(new Quat(h[0], h[1], h[2], h[3])), tr, "view");
                }
            });
            T.Run("conventions: the bone table (Unity HumanBodyBones, VRM, Unreal) is the shared one", () =>
            {
                var bones = conv["bones"];
                T.Equal(19, bones.Count, "joints");
                for (int j = 0; j < 19; j++)
                {
                    T.Equal(Protocol.JointNames[j], bones[j]["joint"].S, "joint order");
                    foreach (var rig in Conventions.BoneRigs)
                        T.Equal(bones[j][rig].S, Conventions.BoneName((Joint)j, rig), Protocol.JointNames[j] + " " + rig);
                }
                T.Equal("Hips", Conventions.UnityHumanBones()[0], "hips");
            });
            T.Run("skeleton: FK of the rest pose stacks the reference offsets; local/world round trip", () =>
            {
                var world = new Quat[19];
                for (int j = 0; j < 19; j++) world[j] = Quat.Identity;
                var p = Skeleton.ForwardKinematics(new Vec3(0, 0.98, 0), world, Skeleton.ReferenceOffsets());
                T.Near(new Vec3(0, 0.98 + 0.10 + 0.20 + 0.22 + 0.10, 0), p[(int)Joint.HEAD], 1e-12, "head");
                T.Near(new Vec3(0.17 + 0.28 + 0.25, 0.98 + 0.30 + 0.17, 0), p[(int)Joint.LEFT_HAND], 1e-12, "left hand");
                var rng = new Random(3);
                for (int j = 0; j < 19; j++) world[j] = Quat.FromRotationVector(rng.NextDouble() - 0.5, rng.NextDouble() - 0.5, rng.NextDouble() - 0.5);
                var back = Skeleton.LocalToWorld(Skeleton.WorldToLocal(world));
                for (int j = 0; j < 19; j++) T.NearRot(world[j], back[j], 1e-12, "joint " + j);
                // Turning the pelvis 90 degrees about +Y swings the left hand from +X to -Z.
                for (int j = 0; j < 19; j++) world[j] = Quat.FromRotationVector(0, Math.PI / 2, 0);
                p = Skeleton.ForwardKinematics(Vec3.Zero, world, Skeleton.ReferenceOffsets());
                T.Near(new Vec3(0, 0.47, -0.70), p[(int)Joint.LEFT_HAND], 1e-12, "turned left hand");
            });
            T.Run("skeleton: a pose's body scale is its bone lengths over the reference's, whatever it does", () =>
            {
                var rng = new Random(5);
                var world = new Quat[19];
                for (int j = 0; j < 19; j++) world[j] = Quat.FromRotationVector(rng.NextDouble() - 0.5, rng.NextDouble() - 0.5, rng.NextDouble() - 0.5);
                var offsets = Skeleton.ReferenceOffsets();
                T.Near(1.0, Skeleton.BodyScale(Skeleton.ForwardKinematics(new Vec3(1, 0.9, 2), world, offsets)), 1e-12, "the reference body");
                for (int j = 0; j < offsets.Length; j++) offsets[j] = offsets[j] * 1.1;
                T.Near(1.1, Skeleton.BodyScale(Skeleton.ForwardKinematics(Vec3.Zero, world, offsets)), 1e-12, "a body 1.1 times as tall");
                T.Near(1.0, Skeleton.BodyScale(new Vec3[19]), 0, "all joints at one point");
            });
        }
    }
}

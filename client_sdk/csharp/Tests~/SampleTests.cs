// The XR avatars sample (Samples~/XRAvatars) in desktop mode, on the stand-in
// UnityEngine and a real `posecast serve`: the bootstrap builds the scene and a
// stand-in Humanoid, joins, replays the recording as this player and as a bot, and two
// avatars (this player's own and the bot's) appear and walk, as the README promises.

using System;
using System.Diagnostics;
using System.IO;
using System.Linq;
using System.Threading;
using Posecast.Client.Unity;
using Posecast.Samples;
using UnityEngine;

namespace Posecast.Client.Tests
{
    public static class SampleTests
    {
        public static void Register()
        {
            var sample = Path.Combine(T.Repo, "client_sdk", "csharp", "Samples~", "XRAvatars");
            T.Run("sample: the recording parses (480 frames, 8 s) and replays looped, allocation-free", () =>
            {
                var rec = TrackerRecording.Parse(File.ReadAllText(Path.Combine(sample, "Resources", "posecast-walk.csv")));
                T.Equal(480, rec.Count, "frames");
                T.Near(8.0, rec.DurationS, 1e-3, "duration");
                var pos = new Vec3[4]; var rot = new Quat[4];
                T.Equal(15, rec.FrameAt(0, pos, rot, new Vec3(1.5, 0, 0)), "valid");
                T.Near(new Vec3(1.501, 1.6254, 0.0524), pos[0], 1e-9, "the head, moved 1.5 m");
                var at1 = pos[0];
                rec.FrameAt(8.0 + 1e-6, pos, rot, new Vec3(1.5, 0, 0));
                T.Near(at1, pos[0], 1e-9, "looped");
                long before = GC.GetAllocatedBytesForCurrentThread();
                for (int k = 0; k < 600; k++) rec.FrameAt(k / 60.0, pos, rot, Vec3.Zero);
                T.Equal(0L, GC.GetAllocatedBytesForCurrentThread() - before, "bytes allocated");
                T.Throws<FormatException>(() => TrackerRecording.Parse("0,15,1,2\n"), "a short line");
                var e = T.Throws<FormatException>(() => TrackerRecording.Parse("# c\n" + string.Join(",", Enumerable.Repeat("0", 30)) + "\n"
                                                                                + string.Join(",", Enumerable.Repeat("0", 30))), "time");
                T.True(e.Message.StartsWith("line 3: time 0 s does not increase"), e.Message);
            });

            T.Run("sample: the stand-in Humanoid is a valid Humanoid whose bones the driver finds", () =>
            {
                var h = SampleHumanoid.Build("H");
                var a = h.GetComponent<Animator>();
                T.True(a.avatar.isHuman && a.avatar.isValid, "valid");
                T.Equal("Hips", a.GetBoneTransform(HumanBodyBones.Hips).name, "hips");
                var hand = a.GetBoneTransform(HumanBodyBones.LeftHand).position;
                T.True(hand.x < -0.5f && Math.Abs(hand.y - 1.4f) < 0.2f, "the left hand out to Unity -x in a T-pose: " + hand);
            });

            if (!T.E2E) return;
            if (Server.Bin() == null)
            {
                T.Run("sample e2e: a real posecast serve", () => { throw new SkipException("no posecast server here (make venv, or set POSECAST_BIN)"); });
                return;
            }
            using (var server = new Server())
            {
                T.Run("sample e2e: desktop mode shows two walking avatars, this player's and the bot's", () =>
                {
                    server.Start(Server.FreePort());
                    Resources.Roots.Add(Path.Combine(sample, "Resources"));
                    int mark = Loop.Mark();
                    var boot = new GameObject("posecast sample").AddComponent<PosecastSampleBootstrap>();
                    boot.Url = server.Url;
                    boot.DevSecret = server.Secret;
                    boot.Room = "sample-room";
                    boot.Mode = SampleMode.Desktop;
                    Func<bool> two = () => boot.Manager != null && boot.Manager.Avatars.Count == 2;
                    var sw = Stopwatch.StartNew();
                    while (!two() && sw.Elapsed.TotalSeconds < 20) { Loop.Frame(mark); Thread.Sleep(16); }
                    T.True(two(), "two avatars: " + (boot.Manager == null ? "no manager" : string.Join(",", boot.Manager.Avatars.Keys)));
                    T.True(boot.Desktop && Camera.main != null && GameObject.FindObjectOfType<Light>() != null, "desktop, a camera, a light");
                    var drivers = boot.Manager.Avatars.Values.ToList();
                    var hips = drivers.Select(d => d.Avatar.GetBoneTransform(HumanBodyBones.Hips)).ToList();
                    T.True(drivers.All(d => d.gameObject.activeSelf), "shown (copies of an inactive template, activated)");
                    var start = hips.Select(h => h.position).ToList();
                    sw.Restart();
                    while (sw.Elapsed.TotalSeconds < 2) { Loop.Frame(mark); Thread.Sleep(16); }
                    for (int i = 0; i < 2; i++)
                    {
                        var p = hips[i].position;
                        float moved = (p - start[i]).magnitude;
                        T.True(moved > 0.3f, drivers[i].Player + " walked " + moved + " m in 2 s");
                        T.True(p.y > 0.6f && p.y < 1.3f, drivers[i].Player + "'s hips at walking height: " + p);
                    }
                    T.True((hips[0].position - hips[1].position).magnitude > 0.5f, "two avatars apart");
                    boot.Manager.Disconnect().Wait();
                    var bot = GameObject.FindObjectOfType<SampleReplay>();
                    foreach (var r in new[] { bot }.Where(r => r != null && r.Own != null)) r.Own.CloseAsync().Wait();
                });
            }
        }
    }
}

// PosecastAvatarManager on the stand-in UnityEngine: avatars spawned on a join (welcome
// members and presence), removed on a leave, on a lost connection and on Disconnect,
// the UnityEvents raised in order and every event passed on; then against a real
// `posecast serve` with a C# and a Python SDK player: both appear and move, the Python
// one goes when it leaves, and a server restart removes and brings back the avatars.

using System;
using System.Collections.Generic;
using System.Diagnostics;
using System.IO;
using System.Linq;
using System.Reflection;
using System.Threading;
using Posecast.Client.Unity;
using UnityEngine;

namespace Posecast.Client.Tests
{
    public static class ManagerTests
    {
        /// <summary>A Humanoid prefab: a root with an Animator and the 19 posecast bones as child
        /// GameObjects, in a T-pose facing +Z.</summary>
        public static GameObject Prefab()
        {
            var root = new GameObject("Ada");
            var animator = root.AddComponent<Animator>();
            foreach (var bone in UnityFrames.HumanBones())
            {
                var b = new GameObject(bone.ToString());
                b.transform.SetParent(root.transform, false);
                animator.Bones[bone] = b.transform;
            }
            return root;
        }

        /// <summary>What the manager raised, in order, as "Event(args)".</summary>
        public sealed class Recorder
        {
            public readonly List<string> Log = new List<string>();
            public readonly List<ClientEvent> Passed = new List<ClientEvent>();

            public Recorder(PosecastAvatarManager m)
            {
                m.Connected.AddListener(() => Add("Connected"));
                m.Joined.AddListener(p => Add("Joined(" + p + ")"));
                m.PlayerJoined.AddListener(p => Add("PlayerJoined(" + p + ")"));
                m.PlayerLeft.AddListener(p => Add("PlayerLeft(" + p + ")"));
                m.Error.AddListener((code, text) => Add("Error(" + code + ")"));
                m.Reconnecting.AddListener((attempt, delay) => Add("Reconnecting(" + attempt + ")"));
                m.Disconnected.AddListener(() => Add("Disconnected"));
                m.EventReceived += e => { lock (Passed) Passed.Add(e); };
            }

            private void Add(string s) { lock (Log) Log.Add(s); }

            public List<string> Take()
            {
                lock (Log) { var l = Log.ToList(); Log.Clear(); return l; }
            }

            public string Joined(List<string> l) { return string.Join(" ", l); }
        }

        private static void OnEvent(PosecastAvatarManager m, ClientEvent e)
        {
            typeof(PosecastAvatarManager).GetMethod("OnEvent", BindingFlags.Instance | BindingFlags.NonPublic).Invoke(m, new object[] { e });
        }

        private static ClientEvent Welcome(string self, params string[] others)
        {
            var members = new[] { self }.Concat(others).Select(p => new Member { Player = p, Name = "name of " + p }).ToArray();
            return new ClientEvent { Kind = EventKind.Welcome, Welcome = new Welcome { Player = self, Members = members } };
        }

        private static ClientEvent Presence(string ev, string player)
        {
            return new ClientEvent { Kind = EventKind.Presence, Presence = new Presence { Event = ev, Player = player, Name = "name of " + player } };
        }

        private static ClientEvent PoseOf(string player, double t, double x)
        {
            var pos = new Vec3[Protocol.NumJoints];
            var rot = new Quat[Protocol.NumJoints];
            for (int j = 0; j < pos.Length; j++) { pos[j] = new Vec3(x, 0.98, 0); rot[j] = Quat.Identity; }
            return new ClientEvent { Kind = EventKind.Pose, Pose = new PlayerPose { Player = player, Seq = (long)(t * 60), T = t, Positions = pos, Rotations = rot } };
        }

        private static PosecastAvatarManager Manager(GameObject prefab)
        {
            var host = new GameObject("posecast");
            host.transform.position = new Vector3(10, 0, 0); // avatars play in the manager's frame
            var m = host.AddComponent<PosecastAvatarManager>();
            m.AvatarPrefab = prefab;
            m.ConnectOnStart = false;
            return m;
        }

        public static void Register()
        {
            T.Run("unity manager: a welcome spawns one avatar per other member, a presence join one more, a leave removes it", () =>
            {
                var prefab = Prefab();
                var m = Manager(prefab);
                var rec = new Recorder(m);
                OnEvent(m, Welcome("me", "ann", "bob"));
                T.Equal("Joined(me) PlayerJoined(ann) PlayerJoined(bob)", rec.Joined(rec.Take()), "events");
                T.Equal("ann,bob", string.Join(",", m.Avatars.Keys.OrderBy(k => k)), "avatars (not mine)");
                var ann = m.Avatars["ann"];
                T.True(ann != null && ann.Player == "ann", "a driver for ann");
                T.Equal("posecast ann (name of ann)", ann.gameObject.name, "named after the player");
                T.True(ann.transform.parent == m.transform, "under the manager");
                var hips = ann.Avatar.GetBoneTransform(HumanBodyBones.Hips);
                T.True(ann.Avatar.gameObject == ann.gameObject && hips != prefab.GetComponent<Animator>().GetBoneTransform(HumanBodyBones.Hips),
                       "the copy's own Animator and bones, not the prefab's");

                OnEvent(m, Presence("join", "cat"));
                OnEvent(m, Presence("stale", "bob"));
                OnEvent(m, Presence("leave", "ann"));
                T.Equal("PlayerJoined(cat) PlayerLeft(ann)", rec.Joined(rec.Take()), "events");
                T.True(ann.gameObject == null && ann == null, "ann's avatar destroyed");
                T.Equal("bob,cat", string.Join(",", m.Avatars.Keys.OrderBy(k => k)), "avatars");
                T.Equal(4, rec.Passed.Count, "every event passed on, a stale presence too");
                T.Equal("stale", rec.Passed[2].Presence.Event, "in order");
            });

            T.Run("unity manager: avatars move with their player's poses, in the manager's frame; the prefab stays put", () =>
            {
                var prefab = Prefab();
                var m = Manager(prefab);
                OnEvent(m, Welcome("me", "bob"));
                for (int k = 0; k < 30; k++) OnEvent(m, PoseOf("bob", 100 + k / 60.0, 0.5));
                m.DriveAvatars(100.4);
                var hips = m.Avatars["bob"].Avatar.GetBoneTransform(HumanBodyBones.Hips).position;
                // posecast (0.5, 0.98, 0) is Unity (-0.5, 0.98, 0), from the manager at (10, 0, 0).
                T.Near(new Vec3(9.5, 0.98, 0), new Vec3(hips.x, hips.y, hips.z), 1e-5, "bob's hips");
                var still = prefab.GetComponent<Animator>().GetBoneTransform(HumanBodyBones.Hips).position;
                T.Near(Vec3.Zero, new Vec3(still.x, still.y, still.z), 0, "the prefab's hips");
            });

            T.Run("unity manager: a lost connection removes every avatar before Reconnecting; the rejoin brings back who is there", () =>
            {
                var m = Manager(Prefab());
                var rec = new Recorder(m);
                OnEvent(m, Welcome("me", "ann", "bob"));
                rec.Take();
                OnEvent(m, new ClientEvent { Kind = EventKind.Error, Error = new ErrorMessage { Code = "RATE_LIMITED", Text = "slow down" } });
                OnEvent(m, new ClientEvent { Kind = EventKind.Reconnecting, Attempt = 1, DelayS = 0.25, Cause = new ConnectionLostException("lost") });
                T.Equal(0, m.Avatars.Count, "no avatars while away");
                OnEvent(m, Welcome("me", "bob"));
                var log = rec.Take();
                T.Equal("Error(RATE_LIMITED) PlayerLeft(ann) PlayerLeft(bob) Reconnecting(1) Joined(me) PlayerJoined(bob)", rec.Joined(log), "events");
            });

            T.Run("unity manager: ShowLocalAvatar spawns this player's own; no prefab still tracks players; a welcome drops who left meanwhile", () =>
            {
                var m = Manager(Prefab());
                m.ShowLocalAvatar = true;
                OnEvent(m, Welcome("me", "ann"));
                T.Equal("ann,me", string.Join(",", m.Avatars.Keys.OrderBy(k => k)), "mine too");
                var bare = Manager(null);
                var rec = new Recorder(bare);
                OnEvent(bare, Welcome("me", "ann", "bob"));
                T.True(bare.Avatars.Count == 2 && bare.Avatars["ann"] == null, "players without avatars");
                rec.Take();
                OnEvent(bare, Welcome("me", "bob", "cat")); // a rejoin without a Reconnecting first
                T.Equal("PlayerLeft(ann) Joined(me) PlayerJoined(cat)", rec.Joined(rec.Take()), "events");
            });

            T.Run("unity manager: Connect without a token raises Error(ConfigInvalidException) and returns false", () =>
            {
                var m = Manager(Prefab());
                var rec = new Recorder(m);
                T.True(!m.Connect().Result, "not connected");
                T.Equal("Error(ConfigInvalidException)", rec.Joined(rec.Take()), "events");
                T.True(m.LastError is ConfigInvalidException && m.Client == null, "LastError, no client");
            });

            T.Run("unity streamer: with a Manager it uses the manager's client and jitter buffer", () =>
            {
                var m = Manager(Prefab());
                var s = new GameObject("rig").AddComponent<PosecastXRStreamer>();
                s.Manager = m;
                T.True(ReferenceEquals(s.Poses, m.Poses), "the manager's buffer");
                T.True(s.Client == null, "no client of its own");
            });

            RegisterE2E();
        }

        private static bool Pump(PosecastAvatarManager m, Func<bool> until, double seconds)
        {
            var sw = Stopwatch.StartNew();
            while (sw.Elapsed.TotalSeconds < seconds)
            {
                m.Pump();
                if (m.Client != null) m.DriveAvatars(m.Client.ServerNow);
                if (until()) return true;
                Thread.Sleep(16);
            }
            return until();
        }

        private static void RegisterE2E()
        {
            if (!T.E2E) return;
            if (Server.Bin() == null)
            {
                T.Run("unity manager e2e: a real posecast serve", () => { throw new SkipException("no posecast server here (make venv, or set POSECAST_BIN)"); });
                return;
            }
            using (var server = new Server())
            {
                T.Run("unity manager e2e: the server starts", () => server.Start(Server.FreePort()));
                if (server.Proc == null) return;
                Player cs = null;
                PosecastAvatarManager m = null;
                Recorder rec = null;
                T.Run("unity manager e2e: a C# and a Python player appear as moving avatars; the Python one goes when it leaves", () =>
                {
                    cs = Player.Join(server, "unity-room", "cs-walker", 1.0).Result;
                    m = Manager(Prefab());
                    rec = new Recorder(m);
                    m.Url = server.Url;
                    m.Room = "unity-room";
                    m.DisplayName = "Unity";
                    int tokens = 0;
                    m.TokenProvider = () => { Interlocked.Increment(ref tokens); return server.Token("unity-room", "unity-me", "spectator"); };
                    T.True(m.Connect().Result, "joined: " + m.LastError);
                    T.True(Pump(m, () => m.Avatars.ContainsKey("cs-walker"), 10), "the C# player's avatar");
                    T.Equal("Connected Joined(unity-me) PlayerJoined(cs-walker)", rec.Joined(rec.Take()), "events");

                    var py = Path.Combine(T.Repo, ".venv", "bin", "python");
                    if (!File.Exists(py)) throw new SkipException("no .venv python");
                    var psi = new ProcessStartInfo(py, string.Join(" ", new[] { Path.Combine(T.Repo, "client_sdk", "csharp", "Tests~", "python_peer.py"),
                                                                                 server.Url, server.Secret, "unity-room", "cs-walker", "3" }))
                    { UseShellExecute = false, RedirectStandardOutput = true, RedirectStandardError = true };
                    using (var proc = Process.Start(psi))
                    {
                        proc.StandardOutput.ReadToEndAsync();
                        var errors = proc.StandardError.ReadToEndAsync();
                        T.True(Pump(m, () => m.Avatars.ContainsKey("py-peer"), 20), "the Python player's avatar: " + rec.Joined(rec.Log));
                        var hips = m.Avatars["py-peer"].Avatar.GetBoneTransform(HumanBodyBones.Hips);
                        var seen = new HashSet<string>();
                        T.True(Pump(m, () => { seen.Add(hips.position.ToString()); return seen.Count > 20; }, 10),
                               "its hips move (walk): " + seen.Count + " places");
                        T.True(hips.position.y > 0.5f && hips.position.y < 1.3f, "standing: hips at " + hips.position);
                        var csHips = m.Avatars["cs-walker"].Avatar.GetBoneTransform(HumanBodyBones.Hips).position;
                        T.True(Math.Abs(csHips.x - (10 - 1.0)) < 0.3, "the C# player's hips where it stands (x = 1 m, Unity -x, from the manager at 10): " + csHips);
                        T.True(proc.WaitForExit(30000), "the peer finished");
                        T.Equal(0, proc.ExitCode, "peer: " + errors.Result);
                    }
                    T.True(Pump(m, () => !m.Avatars.ContainsKey("py-peer"), 10), "the Python player's avatar removed");
                    T.Equal("PlayerJoined(py-peer) PlayerLeft(py-peer)", rec.Joined(rec.Take()), "events");
                    T.Equal(1, tokens, "one token for the join");
                });
                T.Run("unity streamer e2e: without a manager it connects, feeds its buffer and passes every event on", () =>
                {
                    var rig = new GameObject("rig").AddComponent<PosecastXRStreamer>();
                    rig.Url = server.Url;
                    rig.Room = "unity-room";
                    rig.Token = server.Token("unity-room", "unity-rig");
                    var passed = new List<ClientEvent>();
                    rig.EventReceived += e => passed.Add(e);
                    Loop.Call(rig, "Start");
                    Player late = null;
                    try
                    {
                        var sw = Stopwatch.StartNew();
                        Func<bool> done = () => passed.Any(e => e.Kind == EventKind.Welcome)
                                                && passed.Any(e => e.Kind == EventKind.Pose && e.Pose.Player == "cs-walker")
                                                && passed.Any(e => e.Kind == EventKind.Presence && e.Presence.Player == "cs-late");
                        while (!done() && sw.Elapsed.TotalSeconds < 20)
                        {
                            Loop.Call(rig, "Update");
                            if (late == null && rig.Client != null && rig.Client.Connected) late = Player.Join(server, "unity-room", "cs-late", -1.0).Result;
                            Thread.Sleep(16);
                        }
                        T.True(done(), "welcome, poses and a presence join passed on: " + passed.Count + " events");
                        T.True(rig.Poses.Buffer("cs-walker") != null, "its own buffer took the poses");
                    }
                    finally
                    {
                        if (late != null) late.Stop().Wait();
                        if (rig.Client != null) rig.Client.CloseAsync().Wait();
                    }
                });
                T.Run("unity manager e2e: a server restart removes the avatars, then the rejoin brings the C# player back", () =>
                {
                    T.True(m != null && m.Client != null, "joined");
                    // The streamer's and the late player's visit (the test before) is over.
                    T.True(Pump(m, () => m.Avatars.Count == 1, 10), "only the C# walker: " + string.Join(",", m.Avatars.Keys));
                    rec.Take();
                    server.Stop();
                    server.Start(server.Port);
                    T.True(Pump(m, () => m.Avatars.ContainsKey("cs-walker") && rec.Log.Contains("Joined(unity-me)"), 30),
                           "back: " + rec.Joined(rec.Log));
                    var log = rec.Take();
                    // The C# player may rejoin before or after this client: in the welcome's members, or by presence.
                    T.Equal("PlayerLeft(cs-walker) Reconnecting(1)", string.Join(" ", log.Take(2)), "first the avatar goes: " + rec.Joined(log));
                    int joined = log.IndexOf("Joined(unity-me)");
                    T.True(joined > 1 && log.IndexOf("PlayerJoined(cs-walker)") > joined, "then Joined, then the player: " + rec.Joined(log));
                    T.True(log.Skip(2).Take(joined - 2).All(s => s.StartsWith("Reconnecting(")), "only retries between: " + rec.Joined(log));
                    T.True(m.Avatars["cs-walker"] != null && m.Avatars["cs-walker"].gameObject != null, "a fresh avatar");
                    var ev = rec.Passed.Select(e => e.Kind).ToList();
                    T.True(ev.Contains(EventKind.Reconnecting) && ev.Count(k => k == EventKind.Welcome) == 2, "every event passed on");
                });
                T.Run("unity manager e2e: Disconnect removes every avatar, then Disconnected; a bad token is Error(UNAUTHENTICATED)", () =>
                {
                    T.True(m != null, "joined");
                    m.Disconnect().Wait();
                    T.Equal("PlayerLeft(cs-walker) Disconnected", rec.Joined(rec.Take()), "events");
                    T.True(m.Client == null && m.Avatars.Count == 0, "gone");
                    m.TokenProvider = () => "not-a-token";
                    T.True(!m.Connect().Result, "refused");
                    T.Equal("Connected Error(UNAUTHENTICATED) Disconnected", rec.Joined(rec.Take()), "events");
                });
                if (cs != null) cs.Stop().Wait();
            }
        }
    }
}

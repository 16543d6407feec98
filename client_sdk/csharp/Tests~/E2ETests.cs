// End to end against a real `posecast serve` (the repository's .venv, or $POSECAST_BIN;
// skipped where there is none): two C# clients in one room see each other's poses
// (posecast.v2, rebuilt by FK); a Python SDK client in the same room sees the C#
// player, and its poses of that player agree with the C# client's within 1 cm; a
// client pinned to posecast.v1 works too; after the server restarts on the same port
// the C# client reconnects, rejoins and its frames' seq carries on.

using System;
using System.Collections.Generic;
using System.Diagnostics;
using System.IO;
using System.Linq;
using System.Net;
using System.Net.Sockets;
using System.Threading;
using System.Threading.Tasks;

namespace Posecast.Client.Tests
{
    public sealed class Server : IDisposable
    {
        public readonly string Secret = "cs-sdk-test-secret-" + Guid.NewGuid().ToString("N").Substring(0, 16);
        public int Port;
        public Process Proc;
        public string Url { get { return "ws://127.0.0.1:" + Port + "/"; } }

        public static string Bin()
        {
            var env = Environment.GetEnvironmentVariable("POSECAST_BIN");
            if (!string.IsNullOrEmpty(env) && File.Exists(env)) return env;
            var venv = Path.Combine(T.Repo, ".venv", "bin", "posecast");
            return File.Exists(venv) ? venv : null;
        }

        public static int FreePort()
        {
            var l = new TcpListener(IPAddress.Loopback, 0);
            l.Start();
            int port = ((IPEndPoint)l.LocalEndpoint).Port;
            l.Stop();
            return port;
        }

        public void Start(int port)
        {
            Port = port;
            var psi = new ProcessStartInfo(Bin(), "serve --dev --port " + port + " --samples 8 --log-level WARNING")
            {
                UseShellExecute = false, RedirectStandardOutput = true, RedirectStandardError = true,
            };
            psi.EnvironmentVariables["POSECAST_TOKEN_SECRET"] = Secret;
            psi.EnvironmentVariables["POSECAST_CONN_PER_IP_PER_MIN"] = "100000";
            psi.EnvironmentVariables["POSECAST_SOCKETS_PER_IP"] = "100000";
            Proc = Process.Start(psi);
            var ready = new ManualResetEventSlim();
            Proc.OutputDataReceived += (s, e) => { if (e.Data != null && e.Data.Contains("listening on ws://")) ready.Set(); };
            Proc.ErrorDataReceived += (s, e) => { };
            Proc.BeginOutputReadLine();
            Proc.BeginErrorReadLine();
            if (!ready.Wait(TimeSpan.FromSeconds(60))) throw new Exception("posecast serve did not start in 60 s");
        }

        /// <summary>SIGTERM (graceful: bye SERVER_SHUTDOWN to everyone), then wait for the exit.</summary>
        public void Stop()
        {
            if (Proc == null || Proc.HasExited) return;
            using (var kill = Process.Start("kill", "-TERM " + Proc.Id)) kill.WaitForExit();
            if (!Proc.WaitForExit(15000)) Proc.Kill();
            Proc.WaitForExit();
        }

        public void Dispose() { Stop(); }

        public string Token(string room, string player, string role = "player") { return DevTokens.Mint(Secret, room, player, role); }
    }

    /// <summary>A standing player swinging its arms: 4 trackers at time t.</summary>
    public static class Motion
    {
        public static void Trackers(double t, double x0, out Vec3[] pos, out Quat[] quat)
        {
            double s = Math.Sin(2 * Math.PI * 0.5 * t);
            pos = new[]
            {
                new Vec3(x0, 1.65, 0.02 * s), new Vec3(x0 + 0.25, 1.05, 0.15 * s),
                new Vec3(x0 - 0.25, 1.05, -0.15 * s), new Vec3(x0, 1.0, 0.0),
            };
            var yaw = Quat.FromRotationVector(0, 0.2 * s, 0);
            quat = new[] { yaw, Quat.Identity, Quat.Identity, yaw };
        }
    }

    /// <summary>A client that streams at 60 Hz and keeps every event, in the background.</summary>
    public sealed class Player
    {
        public PosecastClient Client;
        public readonly List<ClientEvent> Events = new List<ClientEvent>();
        public readonly List<long> SeqsSent = new List<long>();
        public Exception Failure;
        private CancellationTokenSource _stop = new CancellationTokenSource();
        private Task _task;

        public static async Task<Player> Join(Server s, string room, string player, double x0, ClientOptions opts = null)
        {
            opts = opts ?? new ClientOptions();
            opts.TokenProvider = () => s.Token(room, player);
            opts.BackoffInitialS = 0.2;
            var p = new Player { Client = await PosecastClient.ConnectAsync(s.Url, s.Token(room, player), opts) };
            await p.Client.JoinAsync(room, "C# " + player);
            p._task = Task.Run(() => p.Loop(x0));
            return p;
        }

        private async Task Loop(double x0)
        {
            var clock = Stopwatch.StartNew();
            try
            {
                while (!_stop.IsCancellationRequested)
                {
                    Vec3[] pos; Quat[] quat;
                    Motion.Trackers(clock.Elapsed.TotalSeconds, x0, out pos, out quat);
                    var seq = await Client.SendFrameAsync(pos, quat);
                    ClientEvent e;
                    lock (Events)
                    {
                        if (seq.HasValue) SeqsSent.Add(seq.Value);
                        while (Client.TryGetEvent(out e)) Events.Add(e);
                    }
                    await Task.Delay(16);
                }
            }
            catch (Exception e) { Failure = e; }
        }

        public List<PlayerPose> PosesOf(string player)
        {
            lock (Events) return Events.Where(e => e.Kind == EventKind.Pose && e.Pose.Player == player).Select(e => e.Pose).ToList();
        }

        public bool Saw(EventKind kind) { lock (Events) return Events.Any(e => e.Kind == kind); }

        public async Task Stop()
        {
            _stop.Cancel();
            if (_task != null) await _task;
            await Client.CloseAsync();
        }
    }

    public static class E2ETests
    {
        private static bool WaitFor(Func<bool> cond, double seconds)
        {
            var sw = Stopwatch.StartNew();
            while (sw.Elapsed.TotalSeconds < seconds) { if (cond()) return true; Thread.Sleep(50); }
            return cond();
        }

        /// <summary>Run a program to its end: (exit status, stdout + stderr).</summary>
        private static Tuple<int, string> Exec(string file, string args, Dictionary<string, string> env, int timeoutS)
        {
            var psi = new ProcessStartInfo(file, args) { UseShellExecute = false, RedirectStandardOutput = true, RedirectStandardError = true };
            if (env != null) foreach (var kv in env) psi.EnvironmentVariables[kv.Key] = kv.Value;
            using (var p = Process.Start(psi))
            {
                var err = p.StandardError.ReadToEndAsync();
                string output = p.StandardOutput.ReadToEnd();
                if (!p.WaitForExit(timeoutS * 1000)) { p.Kill(); return Tuple.Create(-1, output + err.Result); }
                return Tuple.Create(p.ExitCode, output + err.Result);
            }
        }

        public static void Register()
        {
            if (!T.E2E) return;
            if (Server.Bin() == null)
            {
                T.Run("e2e: a real posecast serve", () => { throw new SkipException("no posecast server here (make venv, or set POSECAST_BIN)"); });
                return;
            }
            using (var server = new Server())
            {
                T.Run("e2e: the server starts", () => server.Start(Server.FreePort()));
                if (server.Proc == null) return;
                Player a = null, b = null;
                T.Run("e2e: two C# clients in one room see each other's poses (v2, FK from the skeletons)", () =>
                {
                    a = Player.Join(server, "cs-room", "cs-a", 0.0).Result;
                    b = Player.Join(server, "cs-room", "cs-b", 1.5).Result;
                    T.Equal(2, a.Client.Version, "a speaks v2");
                    T.Equal(2, b.Client.Version, "b speaks v2");
                    T.True(WaitFor(() => a.PosesOf("cs-b").Count > 30 && b.PosesOf("cs-a").Count > 30, 20), "poses both ways: "
                           + a.PosesOf("cs-b").Count + ", " + b.PosesOf("cs-a").Count);
                    T.True(a.Failure == null && b.Failure == null, "no failure: " + a.Failure + b.Failure);
                    var pa = b.PosesOf("cs-a").Last();
                    var head = pa.Positions[(int)Joint.HEAD];
                    T.True(Math.Abs(head.X) < 0.5 && head.Y > 1.2 && head.Y < 2.0, "a's head where a's headset is: " + head);
                    T.True(pa.Rotations != null && pa.LocalRotations != null, "rotations");
                    var mine = a.SeqsSent.ToList();
                    T.True(a.PosesOf("cs-a").Any(p => mine.Contains(p.Seq)), "a's own poses echo a's frame seqs");
                    T.True(a.PosesOf("cs-b").Any(p => p.Keyframe) && a.PosesOf("cs-b").Any(p => !p.Keyframe), "keyframes and deltas");
                    T.True(a.Saw(EventKind.Presence), "a saw b join");
                    T.Equal(0L, a.Client.Stats.BadMessages + b.Client.Stats.BadMessages, "no bad messages");
                });
                T.Run("e2e: a Python SDK client in the room sees the C# player; its poses agree with the C# decoder's within 1 cm", () =>
                {
                    T.True(a != null, "the clients joined");
                    var py = Path.Combine(T.Repo, ".venv", "bin", "python");
                    if (!File.Exists(py)) throw new SkipException("no .venv python");
                    var psi = new ProcessStartInfo(py, string.Join(" ", new[] { Path.Combine(T.Repo, "client_sdk", "csharp", "Tests~", "python_peer.py"),
                                                                                 server.Url, server.Secret, "cs-room", "cs-a", "2.5" }))
                    { UseShellExecute = false, RedirectStandardOutput = true, RedirectStandardError = true };
                    string output, errors;
                    using (var proc = Process.Start(psi))
                    {
                        var err = proc.StandardError.ReadToEndAsync();
                        output = proc.StandardOutput.ReadToEnd();
                        T.True(proc.WaitForExit(30000), "the peer finished");
                        errors = err.Result;
                        T.Equal(0, proc.ExitCode, "peer exit status: " + errors);
                    }
                    var got = Json.Parse(output.Trim().Split('\n').Last());
                    var players = got["players"].Items.Select(j => j.S).ToList();
                    T.True(players.Contains("cs-a") && players.Contains("cs-b"), "the peer saw both C# players: " + string.Join(",", players));
                    var mine = b.PosesOf("cs-a").GroupBy(p => p.Seq).ToDictionary(g => g.Key, g => g.Last());
                    int matched = 0;
                    double worst = 0;
                    foreach (var f in got["poses"].Fields)
                    {
                        PlayerPose p;
                        if (!mine.TryGetValue(long.Parse(f.Key), out p)) continue;
                        matched++;
                        for (int j = 0; j < 19; j++)
                        {
                            var q = f.Value[j].Doubles();
                            worst = Math.Max(worst, (p.Positions[j] - new Vec3(q[0], q[1], q[2])).Length);
                        }
                    }
                    Console.WriteLine("    python peer: " + matched + " poses of cs-a matched by seq, largest joint difference " + (worst * 1000).ToString("F3") + " mm");
                    T.True(matched > 30, matched + " poses of cs-a seen by both");
                    T.True(worst < 0.01, "largest joint difference " + worst + " m");
                });
                T.Run("e2e: a T-pose calibration is taken; an implausible one is CALIBRATION_FAILED, and the player goes on", () =>
                {
                    T.True(a != null, "the clients joined");
                    var tpose = new[] { new Vec3(0, 1.62, 0), new Vec3(0.78, 1.42, 0), new Vec3(-0.78, 1.42, 0), new Vec3(0, 0.95, 0) };
                    var q = new[] { Quat.Identity, Quat.Identity, Quat.Identity, Quat.Identity };
                    Func<int> failed = () => { lock (a.Events) return a.Events.Count(e => e.Kind == EventKind.Error && e.Error.Code == "CALIBRATION_FAILED"); };
                    T.True(a.Client.CalibrateTPoseAsync(tpose, q).Result, "sent");
                    var low = (Vec3[])tpose.Clone(); low[0] = new Vec3(0, 0.3, 0); // a head 30 cm above the floor
                    T.True(a.Client.CalibrateTPoseAsync(low, q).Result, "sent");
                    T.True(WaitFor(() => failed() == 1, 10), "one CALIBRATION_FAILED, for the second: " + failed());
                    int poses0 = b.PosesOf("cs-a").Count;
                    T.True(WaitFor(() => b.PosesOf("cs-a").Count > poses0 + 10, 10), "a's poses go on");
                    T.True(a.Failure == null, "no failure: " + a.Failure);
                    var nan = (Vec3[])tpose.Clone(); nan[1] = new Vec3(double.NaN, 1, 0);
                    T.Equal("trackers[1]", T.Throws<OutOfRangeException>(() => a.Client.CalibrateTPoseAsync(nan, q), "NaN: nothing sent").Field, "field");
                });
                T.Run("e2e: a client pinned to posecast.v1 joins and receives pose messages", () =>
                {
                    var c = Player.Join(server, "cs-room", "cs-v1", -1.5, new ClientOptions { Versions = new[] { 1 } }).Result;
                    T.Equal(1, c.Client.Version, "v1");
                    T.True(WaitFor(() => c.PosesOf("cs-a").Count > 10, 15), "v1 poses of a: " + c.PosesOf("cs-a").Count);
                    T.True(c.PosesOf("cs-a").All(p => !p.Keyframe && p.Rotations != null), "v1 poses carry rotations");
                    c.Stop().Wait();
                });
                T.Run("e2e: DevTokens' JWTs join by kid; an unknown kid and a wrong secret are refused UNAUTHENTICATED", () =>
                {
                    var opts = new ClientOptions { Reconnect = false };
                    var ok = PosecastClient.ConnectAsync(server.Url, DevTokens.Mint(server.Secret, "cs-room", "cs-kid", kid: "secret"), opts).Result;
                    ok.JoinAsync("cs-room", "kid").GetAwaiter().GetResult();
                    ok.CloseAsync().Wait();
                    var refused = new Dictionary<string, string>
                    {
                        { DevTokens.Mint(server.Secret, "cs-room", "cs-k2", kid: "retired-2025"), "token kid 'retired-2025' is unknown" },
                        { DevTokens.Mint(new string('w', 32), "cs-room", "cs-k3"), "signature does not verify" },
                    };
                    foreach (var kv in refused)
                    {
                        var c = PosecastClient.ConnectAsync(server.Url, kv.Key, opts).Result;
                        var e = T.Throws<UnauthenticatedException>(() => c.JoinAsync("cs-room", "m").GetAwaiter().GetResult(), kv.Value);
                        T.True(e.Message.Contains(kv.Value), e.Message);
                    }
                });
                T.Run("e2e: the README example compiles and runs against the server", () =>
                {
                    var readme = File.ReadAllText(Path.Combine(T.Repo, "client_sdk", "csharp", "README.md"));
                    int start = readme.IndexOf("```csharp\n");
                    T.True(start >= 0, "a csharp block in the README");
                    start += "```csharp\n".Length;
                    string code = readme.Substring(start, readme.IndexOf("```", start) - start);
                    var dir = Path.Combine(T.Repo, "build", "csharp");
                    File.WriteAllText(Path.Combine(dir, "ReadmeExample.cs"), code);
                    var lib = typeof(PosecastClient).Assembly.Location;
                    T.Equal(0, Exec("mcs", "-langversion:7.2 -nologo -r:" + lib + " -out:" + Path.Combine(dir, "ReadmeExample.exe") + " "
                                    + Path.Combine(dir, "ReadmeExample.cs"), null, 60).Item1, "compiles");
                    var env = new Dictionary<string, string> { { "POSECAST_URL", server.Url }, { "POSECAST_TOKEN_SECRET", server.Secret } };
                    var run = Exec("mono", Path.Combine(dir, "ReadmeExample.exe"), env, 60);
                    T.Equal(0, run.Item1, "exit status: " + run.Item2);
                    T.True(run.Item2.Contains("joined as ada on v2"), "joined: " + run.Item2);
                    T.True(run.Item2.Contains("head at ("), "printed its head: " + run.Item2);
                });
                T.Run("e2e: after a server restart the client reconnects, rejoins and seq carries on; "
                      + "a TokenProvider that throws at the rejoin is retried", () =>
                {
                    T.True(a != null, "the clients joined");
                    int calls = 0; // a spectator whose token endpoint fails twice when the server is back
                    var flakyOptions = new ClientOptions { BackoffInitialS = 0.1, BackoffMaxS = 0.5, PingIntervalS = 0 };
                    flakyOptions.TokenProvider = () =>
                    {
                        int n = Interlocked.Increment(ref calls);
                        if (n == 2 || n == 3) throw new InvalidOperationException("token endpoint: HTTP 503");
                        return server.Token("cs-room", "cs-flaky", "spectator");
                    };
                    var flaky = PosecastClient.ConnectAsync(server.Url, null, flakyOptions).Result;
                    flaky.JoinAsync("cs-room", "flaky").Wait();
                    long before;
                    lock (a.Events) before = a.SeqsSent.Last();
                    int poses0 = a.PosesOf("cs-b").Count;
                    server.Stop();
                    server.Start(server.Port);
                    var causes = new List<Exception>();
                    Exception flakyEnd = null;
                    T.True(WaitFor(() =>
                    {
                        try
                        {
                            ClientEvent e;
                            while (flaky.TryGetEvent(out e)) if (e.Kind == EventKind.Reconnecting) causes.Add(e.Cause);
                        }
                        catch (Exception e) { flakyEnd = e; return true; }
                        return flaky.Stats.Reconnects >= 1;
                    }, 30), "the flaky client rejoined");
                    T.True(flakyEnd == null, "the flaky client went on, not ended by " + flakyEnd);
                    T.Equal(4, calls, "TokenProvider calls: the join, two that threw, the rejoin");
                    var threw = causes.OfType<TokenProviderException>().ToList();
                    T.Equal(2, threw.Count, "reconnecting after each throw: " + string.Join(", ", causes.Select(c => c.GetType().Name)));
                    T.True(threw[0].InnerException is InvalidOperationException && threw[0].Message.Contains("HTTP 503"), threw[0].Message);
                    flaky.CloseAsync().Wait();
                    T.True(WaitFor(() => a.Saw(EventKind.Reconnecting), 10), "a Reconnecting event");
                    T.True(WaitFor(() => a.Client.Connected && a.PosesOf("cs-b").Count > poses0 + 30, 30),
                           "poses of b again: " + (a.PosesOf("cs-b").Count - poses0));
                    T.True(a.Failure == null, "no failure: " + a.Failure);
                    Console.WriteLine("    restart: reconnects " + a.Client.Stats.Reconnects + ", seq " + before + " -> " + a.SeqsSent.Last()
                                      + ", frames dropped while away " + a.Client.Stats.FramesDropped);
                    T.True(a.Client.Stats.Reconnects >= 1, "reconnects counted");
                    long after;
                    lock (a.Events) after = a.SeqsSent.Last();
                    T.True(after > before, "seq went on: " + before + " then " + after);
                    int welcomes;
                    lock (a.Events) welcomes = a.Events.Count(e => e.Kind == EventKind.Welcome);
                    T.True(welcomes >= 2, welcomes + " welcomes");
                });
                T.Run("e2e: a TokenProvider that throws fails the first join with TokenProviderException", () =>
                {
                    var c = PosecastClient.ConnectAsync(server.Url, null, new ClientOptions
                    {
                        TokenProvider = () => { throw new InvalidOperationException("no session cookie"); },
                    }).Result;
                    try
                    {
                        var e = T.Throws<TokenProviderException>(() => c.JoinAsync("cs-room", "nobody").GetAwaiter().GetResult(), "join");
                        T.True(e.InnerException is InvalidOperationException, "the provider's exception inside");
                        T.True(e.Message == "the TokenProvider threw InvalidOperationException: no session cookie", e.Message);
                    }
                    finally { c.CloseAsync().Wait(); }
                });
                T.Run("e2e: a TokenProvider that returns no token fails the join with ConfigInvalidException", () =>
                {
                    var c = PosecastClient.ConnectAsync(server.Url, null, new ClientOptions { TokenProvider = () => null }).Result;
                    try
                    {
                        var e = T.Throws<ConfigInvalidException>(() => c.JoinAsync("cs-room", "nobody").GetAwaiter().GetResult(), "join");
                        T.True(e.Message.StartsWith("the TokenProvider returned null"), e.Message);
                    }
                    finally { c.CloseAsync().Wait(); }
                });
                T.Run("e2e: with the server gone for good, reconnects retry, then give up with ConnectFailedException", () =>
                {
                    var opts = new ClientOptions { MaxReconnectAttempts = 2, BackoffInitialS = 0.05, BackoffMaxS = 0.1, PingIntervalS = 0 };
                    var c = PosecastClient.ConnectAsync(server.Url, server.Token("cs-room", "cs-quitter"), opts).Result;
                    try
                    {
                        c.JoinAsync("cs-room", "quitter").Wait();
                        server.Stop(); // SERVER_SHUTDOWN, then the port refuses
                        int reconnecting = 0;
                        Exception end = null;
                        T.True(WaitFor(() =>
                        {
                            try
                            {
                                ClientEvent e;
                                while (c.TryGetEvent(out e)) if (e.Kind == EventKind.Reconnecting) reconnecting++;
                            }
                            catch (Exception e) { end = e; }
                            return end != null;
                        }, 30), "the client gave up");
                        var f = end as ConnectFailedException;
                        T.True(f != null, "gave up with " + end);
                        T.True(f.Url == server.Url && f.Reason.StartsWith("connection refused"), f.Message);
                        T.Equal(2, reconnecting, "Reconnecting events, one per attempt");
                    }
                    finally { c.CloseAsync().Wait(); }
                });
                if (a != null) a.Stop().Wait();
                if (b != null) b.Stop().Wait();
            }
        }
    }
}

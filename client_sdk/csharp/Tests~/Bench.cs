// The decode benchmark: PosecastTests.exe --bench DIR decodes DIR/room_v2.bin (a 60 s,
// 8-player room as one client receives it, written by bench_stream.py) through the
// session core, records and FK included, and DIR/room_v1.bin (the same room as v1
// pose messages); prints poses per second per core (process CPU time, best of 3).

using System;
using System.Collections.Generic;
using System.Diagnostics;
using System.IO;

namespace Posecast.Client.Tests
{
    public static class Bench
    {
        private static List<byte[]> Read(string path)
        {
            var all = File.ReadAllBytes(path);
            var out_ = new List<byte[]>();
            for (int at = 0; at < all.Length;)
            {
                int n = BitConverter.ToInt32(all, at);
                var b = new byte[n];
                Buffer.BlockCopy(all, at + 4, b, 0, n);
                out_.Add(b);
                at += 4 + n;
            }
            return out_;
        }

        private static double Rate(Func<long> pass)
        {
            double best = 0;
            var me = Process.GetCurrentProcess();
            for (int k = 0; k < 3; k++)
            {
                me.Refresh();
                var c0 = me.TotalProcessorTime;
                long poses = pass();
                me.Refresh();
                best = Math.Max(best, poses / (me.TotalProcessorTime - c0).TotalSeconds);
            }
            return best;
        }

        public static int Run(string dir)
        {
            var v2 = Read(Path.Combine(dir, "room_v2.bin"));
            var v1 = Read(Path.Combine(dir, "room_v1.bin"));
            double r2 = Rate(() =>
            {
                var s = new ClientSession();
                s.Connected(Protocol.V2);
                long n = 0;
                foreach (var b in v2) foreach (var e in s.Receive(b, 0).Events) if (e.Kind == EventKind.Pose) n++;
                if (s.Stats.BadMessages != 0) throw new Exception("bad messages in the stream");
                return n;
            });
            double r1 = Rate(() =>
            {
                var s = new ClientSession();
                s.Connected(Protocol.V1);
                long n = 0;
                foreach (var b in v1) foreach (var e in s.Receive(b, 0).Events) if (e.Kind == EventKind.Pose) n++;
                return n;
            });
            Console.WriteLine("{\"csharp_v2_poses_per_s\": " + Math.Round(r2) + ", \"csharp_v1_poses_per_s\": " + Math.Round(r1)
                              + ", \"runtime\": \"" + Type.GetType("Mono.Runtime").GetMethod("GetDisplayName",
                                  System.Reflection.BindingFlags.NonPublic | System.Reflection.BindingFlags.Static).Invoke(null, null) + "\"}");
            return 0;
        }
    }
}

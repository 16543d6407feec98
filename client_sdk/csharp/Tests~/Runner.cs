// The C# SDK's test runner: every suite registers its checks with T.Run; the closing
// line "N passed, N failed" is what CI reads, and the exit status is non-zero on any
// failure. Usage: mono PosecastTests.exe [--repo DIR] [--only SUITE] [--no-e2e]

using System;
using System.Collections.Generic;
using System.Diagnostics;
using System.IO;

namespace Posecast.Client.Tests
{
    public sealed class SkipException : Exception { public SkipException(string m) : base(m) { } }

    public static class T
    {
        public static int Passed, Failed, Skipped;
        public static string Repo;
        public static bool Verbose;
        public static bool E2E = true;
        private static readonly List<string> Failures = new List<string>();

        public static void Run(string name, Action check)
        {
            try
            {
                check();
                Passed++;
                if (Verbose) Console.WriteLine("  ok   " + name);
            }
            catch (SkipException e)
            {
                Skipped++;
                Console.WriteLine("  skip " + name + ": " + e.Message);
            }
            catch (Exception e)
            {
                Failed++;
                string why = e is AssertException ? e.Message : e.ToString();
                Failures.Add(name + ": " + why);
                Console.WriteLine("  FAIL " + name + ": " + why);
            }
        }

        public static void True(bool cond, string what)
        {
            if (!cond) throw new AssertException(what);
        }

        public static void Equal<TV>(TV want, TV got, string what)
        {
            if (!EqualityComparer<TV>.Default.Equals(want, got))
                throw new AssertException(what + ": want " + want + ", got " + got);
        }

        public static void Near(double want, double got, double tol, string what)
        {
            if (!(Math.Abs(want - got) <= tol)) throw new AssertException(what + ": want " + want + ", got " + got + " (tol " + tol + ")");
        }

        public static void Near(Vec3 want, Vec3 got, double tol, string what)
        {
            Near(want.X, got.X, tol, what + ".x"); Near(want.Y, got.Y, tol, what + ".y"); Near(want.Z, got.Z, tol, what + ".z");
        }

        /// <summary>Rotations equal component-wise up to sign (q and -q are one rotation).</summary>
        public static void NearRot(Quat want, Quat got, double tol, string what)
        {
            double a = Math.Max(Math.Max(Math.Abs(want.X - got.X), Math.Abs(want.Y - got.Y)), Math.Max(Math.Abs(want.Z - got.Z), Math.Abs(want.W - got.W)));
            double b = Math.Max(Math.Max(Math.Abs(want.X + got.X), Math.Abs(want.Y + got.Y)), Math.Max(Math.Abs(want.Z + got.Z), Math.Abs(want.W + got.W)));
            if (!(Math.Min(a, b) <= tol)) throw new AssertException(what + ": want " + want + ", got " + got);
        }

        public static TE Throws<TE>(Action a, string what) where TE : Exception
        {
            try { a(); }
            catch (TE e) { return e; }
            catch (Exception e) { throw new AssertException(what + ": threw " + e.GetType().Name + " " + e.Message + ", not " + typeof(TE).Name); }
            throw new AssertException(what + ": did not throw " + typeof(TE).Name);
        }

        public static byte[] Hex(string h)
        {
            var b = new byte[h.Length / 2];
            for (int i = 0; i < b.Length; i++) b[i] = Convert.ToByte(h.Substring(2 * i, 2), 16);
            return b;
        }

        public static string ToHex(byte[] b)
        {
            var sb = new System.Text.StringBuilder(b.Length * 2);
            foreach (var x in b) sb.Append(x.ToString("x2"));
            return sb.ToString();
        }

        public static Json Load(params string[] parts)
        {
            var path = Path.Combine(Repo, Path.Combine(parts));
            return Json.Parse(File.ReadAllText(path));
        }

        public static int Main(string[] args)
        {
            Repo = Directory.GetCurrentDirectory();
            string only = null;
            E2E = true;
            for (int i = 0; i < args.Length; i++)
            {
                if (args[i] == "--repo") Repo = args[++i];
                else if (args[i] == "--only") only = args[++i];
                else if (args[i] == "--no-e2e") E2E = false;
                else if (args[i] == "-v") Verbose = true;
                else if (args[i] == "--bench") return Bench.Run(args[++i]);
            }
            var clock = Stopwatch.StartNew();
            var suites = new List<KeyValuePair<string, Action>>
            {
                new KeyValuePair<string, Action>("errors", ErrorsTests.Register),
                new KeyValuePair<string, Action>("vectors", VectorTests.Register),
                new KeyValuePair<string, Action>("codec", CodecTests.Register),
                new KeyValuePair<string, Action>("interp", InterpTests.Register),
                new KeyValuePair<string, Action>("delay", DelayTests.Register),
                new KeyValuePair<string, Action>("clock", ClockTests.Register),
                new KeyValuePair<string, Action>("session", SessionTests.Register),
                new KeyValuePair<string, Action>("connect", ConnectTests.Register),
                new KeyValuePair<string, Action>("unity", UnityTests.Register),
                new KeyValuePair<string, Action>("manager", ManagerTests.Register),
                new KeyValuePair<string, Action>("alloc", AllocTests.Register),
                new KeyValuePair<string, Action>("sample", SampleTests.Register),
                new KeyValuePair<string, Action>("api", ApiTests.Register),
                new KeyValuePair<string, Action>("e2e", E2ETests.Register),
            };
            foreach (var s in suites)
            {
                if (only != null && only != s.Key) continue;
                int before = Passed + Failed;
                var t0 = clock.Elapsed.TotalSeconds;
                s.Value();
                Console.WriteLine(string.Format("{0,-12} {1,5} checks  {2,6:F2} s", s.Key, Passed + Failed - before,
                                                clock.Elapsed.TotalSeconds - t0));
            }
            Console.WriteLine(Passed + " passed, " + Failed + " failed" + (Skipped > 0 ? ", " + Skipped + " skipped" : ""));
            return Failed == 0 ? 0 : 1;
        }
    }

    public sealed class AssertException : Exception { public AssertException(string m) : base(m) { } }
}

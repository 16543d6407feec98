// The stand-in UnityEngine is held to API.md: every UnityEngine type and member the
// Unity layer and the sample refer to, as compiled (read with Mono.Cecil, which
// mono-devel brings), must be listed there with Unity's signature, and every listed one
// must still be used. Skipped where Mono.Cecil is missing (run.sh defines CECIL).

using System;
using System.Collections.Generic;
using System.IO;
using System.Linq;
using System.Text.RegularExpressions;
#if CECIL
using Mono.Cecil;
#endif

namespace Posecast.Client.Tests
{
    public static class ApiTests
    {
        /// <summary>The keys listed in API.md (between the double backticks of a "- " line).</summary>
        public static HashSet<string> Listed(string apiMd)
        {
            var keys = new HashSet<string>();
            foreach (Match m in Regex.Matches(File.ReadAllText(apiMd), "^- ``(.+?)`` — ", RegexOptions.Multiline)) keys.Add(m.Groups[1].Value);
            return keys;
        }

#if CECIL
        private static bool InUnity(TypeReference t)
        {
            var g = t as GenericInstanceType;
            if (g != null) t = g.ElementType;
            var scope = t.Scope == null ? null : t.Scope.Name;
            return scope == "UnityEngine" || (t.Namespace != null && t.Namespace.StartsWith("UnityEngine"));
        }

        /// <summary>Every reference of the assemblies into UnityEngine, as API.md keys them.</summary>
        public static SortedSet<string> Used(params string[] assemblies)
        {
            var used = new SortedSet<string>(StringComparer.Ordinal);
            foreach (var path in assemblies)
                using (var module = ModuleDefinition.ReadModule(path))
                {
                    foreach (var t in module.GetTypeReferences()) if (t.Scope != null && t.Scope.Name == "UnityEngine") used.Add(t.FullName);
                    foreach (var r in module.GetMemberReferences()) if (InUnity(r.DeclaringType)) used.Add(r.FullName);
                }
            return used;
        }
#endif

        public static void Register()
        {
            T.Run("api: every UnityEngine type and member the Unity layer and the sample use is in API.md, with no stale entry", () =>
            {
#if CECIL
                var dir = Path.GetDirectoryName(typeof(ApiTests).Assembly.Location);
                var used = Used(Path.Combine(dir, "Posecast.Client.Unity.dll"), Path.Combine(dir, "Posecast.Samples.XRAvatars.dll"));
                var listed = Listed(Path.Combine(T.Repo, "client_sdk", "csharp", "Tests~", "UnityStub", "API.md"));
                var missing = used.Where(u => !listed.Contains(u)).ToList();
                var stale = listed.Where(l => !used.Contains(l)).OrderBy(l => l, StringComparer.Ordinal).ToList();
                Console.WriteLine("    " + used.Count + " UnityEngine references, " + listed.Count + " listed");
                T.True(used.Count > 100, "references read: " + used.Count);
                T.True(missing.Count == 0, "not in API.md:\n      " + string.Join("\n      ", missing));
                T.True(stale.Count == 0, "in API.md, no longer used:\n      " + string.Join("\n      ", stale));
#else
                throw new SkipException("no Mono.Cecil here (mono-devel brings it)");
#endif
            });
        }
    }
}

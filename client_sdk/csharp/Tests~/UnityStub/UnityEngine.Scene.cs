// The stand-in's scene-building types the sample uses (see API.md): primitives,
// renderers and colliders (no meshes), Camera, Light, TextAsset, Resources, Time.

using System;
using System.Collections.Generic;
using System.Linq;

namespace UnityEngine
{
    public enum PrimitiveType { Sphere, Capsule, Cylinder, Cube, Plane, Quad }
    public sealed class MeshFilter : Component { }
    public class Renderer : Component { }
    public sealed class MeshRenderer : Renderer { }
    public class Collider : Component { }
    public sealed class SphereCollider : Collider { }
    public sealed class CapsuleCollider : Collider { }
    public sealed class MeshCollider : Collider { }

    public sealed class Camera : Behaviour
    {
        /// <summary>The first enabled camera tagged MainCamera, or null.</summary>
        public static Camera main
        {
            get
            {
                lock (Live)
                    foreach (var o in Live)
                    {
                        var c = o as Camera;
                        if (c != null && !c.Destroyed && c.gameObject != null && c.gameObject.tag == "MainCamera") return c;
                    }
                return null;
            }
        }
    }

    public enum LightType { Spot, Directional, Point, Area }
    public sealed class Light : Behaviour
    {
        private LightType _type = LightType.Point;
        public LightType type { get { return _type; } set { _type = value; } }
    }

    public class TextAsset : Object
    {
        private readonly string _text;
        public TextAsset(string text) { _text = text; }
        public string text { get { return _text; } }
    }

    /// <summary>Assets under a Resources folder, by path without extension. The stand-in reads
    /// them from the folders a test lists (Roots).</summary>
    public static class Resources
    {
        public static readonly List<string> Roots = new List<string>();

        public static T Load<T>(string path) where T : Object
        {
            foreach (var root in Roots)
                foreach (var ext in new[] { ".txt", ".csv", ".json", ".bytes" })
                {
                    var file = System.IO.Path.Combine(root, path + ext);
                    if (typeof(T) == typeof(TextAsset) && System.IO.File.Exists(file)) return (T)(Object)new TextAsset(System.IO.File.ReadAllText(file));
                }
            return null;
        }
    }

    /// <summary>Time.time: seconds since the start of the game (the stand-in: of the process).</summary>
    public static class Time
    {
        private static readonly System.Diagnostics.Stopwatch Clock = System.Diagnostics.Stopwatch.StartNew();
        public static float time { get { return (float)Clock.Elapsed.TotalSeconds; } }
    }
}

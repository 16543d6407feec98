// A stand-in for the UnityEngine types Runtime/Unity and the sample use, so run.sh can
// compile the Unity layer and test its logic on Mono (UnityTests, ManagerTests,
// SampleTests). No copy of Unity's own assemblies can be had from the package registries
// this project reaches, so this is written from Unity's scripting reference: every
// member the package uses is listed with Unity's signature in API.md, and ApiTests
// holds the compiled assemblies' references to that list (same names, kinds and
// types). The behaviour is the part the tests need (Quaternion's Hamilton product, a
// Transform hierarchy without scale, Instantiate and Destroy, an Avatar's T-pose
// skeleton, XR devices the test sets up); members marked test-only are not Unity's.
// Not shipped: Unity does not import Tests~. Split by module: UnityEngine.cs (core),
// .Animation.cs, .Scene.cs, .Events.cs, .XR.cs.

using System;
using System.Collections.Generic;
using System.Linq;

namespace UnityEngine
{
    /// <summary>Unity's base of every engine object. A destroyed one compares equal to
    /// null, as in Unity (its == is overloaded).</summary>
    public class Object
    {
        private string _name = "";
        internal bool Destroyed;
        public string name
        {
            get { var c = this as Component; return c != null && !ReferenceEquals(c.gameObject, null) ? c.gameObject.name : _name; }
            set { var c = this as Component; if (c != null && !ReferenceEquals(c.gameObject, null)) c.gameObject.name = value; else _name = value; }
        }

        public static bool operator ==(Object a, Object b)
        {
            bool aNull = ReferenceEquals(a, null) || a.Destroyed, bNull = ReferenceEquals(b, null) || b.Destroyed;
            if (aNull || bNull) return aNull && bNull;
            return ReferenceEquals(a, b);
        }
        public static bool operator !=(Object a, Object b) { return !(a == b); }
        public override bool Equals(object other) { return other is Object && this == (Object)other; }
        public override int GetHashCode() { return base.GetHashCode(); }
        public static implicit operator bool(Object exists) { return exists != null; }

        /// <summary>A copy of `original` under `parent`: for a GameObject its whole hierarchy,
        /// every component copied (an Animator's bones moved to the copy's), Awake called on
        /// each MonoBehaviour of the copy, as Unity does.</summary>
        public static T Instantiate<T>(T original, Transform parent) where T : Object
        {
            var go = original as GameObject;
            if (go == null) throw new NotSupportedException("the stand-in instantiates GameObjects only");
            var copy = go.CloneTree(parent);
            return (T)(Object)copy;
        }

        /// <summary>The first live object of type T made so far (Unity: the first active one loaded).</summary>
        public static T FindObjectOfType<T>() where T : Object
        {
            lock (Live)
                foreach (var o in Live)
                {
                    var t = o as T;
                    if (t != null && !t.Destroyed) return t;
                }
            return null;
        }

        internal static readonly List<Object> Live = new List<Object>();

        public Object() { lock (Live) Live.Add(this); }

        /// <summary>Destroys a GameObject (its children too) or a component. Unity destroys at the
        /// end of the frame; the stand-in at once (tests check `== null` after a frame).</summary>
        public static void Destroy(Object obj)
        {
            if (ReferenceEquals(obj, null)) return;
            var go = obj as GameObject;
            if (go != null) { go.DestroyTree(); return; }
            obj.Destroyed = true;
        }
    }

    /// <summary>A scene object: a Transform and components. Components must be added with
    /// AddComponent (which calls a MonoBehaviour's Awake), as in Unity.</summary>
    public sealed class GameObject : Object
    {
        internal readonly List<Component> Components = new List<Component>();
        private readonly Transform _transform;

        public GameObject() : this("New Game Object") { }

        public GameObject(string name)
        {
            this.name = name;
            _transform = new Transform();
            _transform.Attach(this);
        }

        public Transform transform { get { return _transform; } }
        public GameObject gameObject { get { return this; } }
        private string _tag = "Untagged";
        public string tag { get { return _tag; } set { _tag = value; } }
        private bool _active = true;
        public bool activeSelf { get { return _active; } }

        public bool activeInHierarchy
        {
            get
            {
                for (var t = transform; t != null; t = t.parent)
                    if (!ReferenceEquals(t.gameObject, null) && !t.gameObject._active) return false;
                return true;
            }
        }

        /// <summary>As Unity: activating calls Awake on the components (and those below) not yet awake.</summary>
        public void SetActive(bool value)
        {
            _active = value;
            if (!value) return;
            var all = new List<Transform>();
            transform.Walk(all);
            foreach (var t in all)
                if (!ReferenceEquals(t.gameObject, null) && t.gameObject.activeInHierarchy)
                    foreach (var c in t.gameObject.Components.ToArray())
                    {
                        var mb = c as MonoBehaviour;
                        if (mb != null) mb.CallAwake();
                    }
        }

        public T AddComponent<T>() where T : Component
        {
            var c = (T)Activator.CreateInstance(typeof(T), true);
            c.Attach(this);
            var mb = c as MonoBehaviour;
            if (mb != null && activeInHierarchy) mb.CallAwake();
            return c;
        }

        /// <summary>A primitive with its MeshFilter, MeshRenderer and Collider (no mesh in the stand-in).</summary>
        public static GameObject CreatePrimitive(PrimitiveType type)
        {
            var go = new GameObject(type.ToString());
            go.AddComponent<MeshFilter>();
            go.AddComponent<MeshRenderer>();
            if (type == PrimitiveType.Sphere) go.AddComponent<SphereCollider>();
            else if (type == PrimitiveType.Capsule) go.AddComponent<CapsuleCollider>();
            else go.AddComponent<MeshCollider>();
            return go;
        }

        public T GetComponent<T>()
        {
            foreach (var c in Components) if (c is T && !c.Destroyed) return (T)(object)c;
            return default(T);
        }

        public T GetComponentInChildren<T>()
        {
            var all = new List<Transform>();
            transform.Walk(all);
            foreach (var t in all)
            {
                if (ReferenceEquals(t.gameObject, null)) continue;
                var c = t.gameObject.GetComponent<T>();
                if (c != null) return c;
            }
            return default(T);
        }

        internal GameObject CloneTree(Transform parent)
        {
            var map = new Dictionary<Transform, Transform>();
            var copy = CloneNode(this, map);
            copy.name = name + "(Clone)";
            foreach (var kv in map)
                if (!ReferenceEquals(kv.Key.gameObject, null))
                    foreach (var c in kv.Key.gameObject.Components)
                        if (!(c is Transform)) c.CopyTo(kv.Value.gameObject, map);
            copy._active = _active;
            if (parent != null) copy.transform.SetParent(parent, false);
            foreach (var kv in map)
                if (kv.Value.gameObject.activeInHierarchy)
                    foreach (var c in kv.Value.gameObject.Components)
                    {
                        var mb = c as MonoBehaviour;
                        if (mb != null) mb.CallAwake();
                    }
            return copy;
        }

        private static GameObject CloneNode(GameObject g, Dictionary<Transform, Transform> map)
        {
            var copy = new GameObject(g.name);
            copy._active = g._active;
            copy.transform.localPosition = g.transform.localPosition;
            copy.transform.localRotation = g.transform.localRotation;
            copy.transform.localScale = g.transform.localScale;
            map[g.transform] = copy.transform;
            foreach (var child in g.transform.Children)
            {
                if (ReferenceEquals(child.gameObject, null)) throw new NotSupportedException("a child Transform without a GameObject");
                CloneNode(child.gameObject, map).transform.SetParent(copy.transform, false);
            }
            return copy;
        }

        internal void DestroyTree()
        {
            Destroyed = true;
            foreach (var c in Components) c.Destroyed = true;
            foreach (var child in transform.Children.ToArray())
                if (!ReferenceEquals(child.gameObject, null)) child.gameObject.DestroyTree();
            if (transform.parent != null) transform.SetParent(null, false);
        }
    }

    public class Component : Object
    {
        private Transform _transform;
        private GameObject _gameObject;

        /// <summary>Unity: read-only. The stand-in lets a test set one on a component built
        /// without a GameObject (the older UnityTests build avatars so).</summary>
        public Transform transform
        {
            get { return _gameObject != null ? _gameObject.transform : (_transform ?? (_transform = this as Transform ?? new Transform())); }
            set { _transform = value; }
        }

        public GameObject gameObject { get { return _gameObject; } }

        internal virtual void ResetCopy() { }

        internal void Attach(GameObject go)
        {
            _gameObject = go;
            go.Components.Add(this);
        }

        /// <summary>What Instantiate does with this component: a copy on `into` (fields copied,
        /// references inside the copied hierarchy moved to the copy's).</summary>
        internal virtual void CopyTo(GameObject into, Dictionary<Transform, Transform> map)
        {
            var c = (Component)MemberwiseClone();
            c._gameObject = null; c._transform = null; c.Destroyed = false;
            c.ResetCopy();
            c.Attach(into);
        }

        public T GetComponent<T>() { return _gameObject != null ? _gameObject.GetComponent<T>() : (this is T ? (T)(object)this : default(T)); }

        public T GetComponentInChildren<T>()
        {
            if (_gameObject != null) return _gameObject.GetComponentInChildren<T>();
            return this is T ? (T)(object)this : default(T);
        }

        /// <summary>The components of type T here and below (the stand-in: Transforms, and the
        /// components of GameObjects).</summary>
        public T[] GetComponentsInChildren<T>(bool includeInactive)
        {
            var all = new List<Transform>();
            transform.Walk(all);
            var found = new List<T>();
            foreach (var t in all)
            {
                if (t is T) { found.Add((T)(object)t); continue; }
                if (ReferenceEquals(t.gameObject, null)) continue;
                foreach (var c in t.gameObject.Components) if (c is T) found.Add((T)(object)c);
            }
            return found.ToArray();
        }
    }

    public class Behaviour : Component
    {
        private bool _enabled = true;
        public bool enabled { get { return _enabled; } set { _enabled = value; } }
    }

    /// <summary>Unity calls Awake when the component is added (AddComponent) or its
    /// GameObject instantiated; Start, Update, LateUpdate and OnDestroy by the player loop,
    /// which a test calls by hand (Loop).</summary>
    public class MonoBehaviour : Behaviour
    {
        private bool _awake;
        internal override void ResetCopy() { _awake = false; }
        internal void CallAwake()
        {
            if (_awake) return;
            _awake = true;
            Loop.Call(this, "Awake");
        }
    }

    /// <summary>Test-only: Unity's player loop by hand (Unity calls these itself).</summary>
    public static class Loop
    {
        private static readonly HashSet<MonoBehaviour> Started = new HashSet<MonoBehaviour>();

        /// <summary>How many objects exist now: Frame(mark) runs only those made after.</summary>
        public static int Mark() { lock (Object.Live) return Object.Live.Count; }

        /// <summary>One frame for the MonoBehaviours made since `mark` that are enabled in an active
        /// GameObject: Start (once), then every Update, then every LateUpdate, as Unity orders them.</summary>
        public static void Frame(int mark)
        {
            List<MonoBehaviour> live;
            lock (Object.Live)
                live = Object.Live.Skip(mark).OfType<MonoBehaviour>()
                    .Where(b => !b.Destroyed && b.enabled && b.gameObject != null && b.gameObject.activeInHierarchy).ToList();
            foreach (var b in live) if (Started.Add(b)) Call(b, "Start");
            foreach (var b in live) if (!b.Destroyed) Call(b, "Update");
            foreach (var b in live) if (!b.Destroyed) Call(b, "LateUpdate");
        }

        public static void Call(MonoBehaviour b, string message)
        {
            var m = b.GetType().GetMethod(message, System.Reflection.BindingFlags.Instance | System.Reflection.BindingFlags.Public
                                                   | System.Reflection.BindingFlags.NonPublic);
            if (m != null && m.GetParameters().Length == 0) m.Invoke(b, null);
        }
    }

    /// <summary>A data asset: instances come from CreateInstance (or the editor), never `new`.</summary>
    public class ScriptableObject : Object
    {
        public static T CreateInstance<T>() where T : ScriptableObject
        {
            return (T)Activator.CreateInstance(typeof(T), true);
        }
    }

    [AttributeUsage(AttributeTargets.Field, AllowMultiple = true)]
    public sealed class TooltipAttribute : Attribute { public TooltipAttribute(string tooltip) { } }

    [AttributeUsage(AttributeTargets.Field, AllowMultiple = true)]
    public class HeaderAttribute : Attribute { public HeaderAttribute(string header) { } }

    [AttributeUsage(AttributeTargets.Field)]
    public sealed class SerializeField : Attribute { }

    [AttributeUsage(AttributeTargets.Class, Inherited = false)]
    public sealed class CreateAssetMenuAttribute : Attribute
    {
        public string fileName { get; set; }
        public string menuName { get; set; }
        public int order { get; set; }
    }

    [AttributeUsage(AttributeTargets.Class, AllowMultiple = true)]
    public sealed class RequireComponent : Attribute { public RequireComponent(Type requiredComponent) { } }

    public static class Debug
    {
        public static readonly List<string> Warnings = new List<string>();
        public static readonly List<string> Errors = new List<string>();
        public static void Log(object message) { }
        public static void LogWarning(object message) { Warnings.Add(message == null ? "" : message.ToString()); }
        public static void LogError(object message) { Errors.Add(message == null ? "" : message.ToString()); }
        public static void LogException(Exception exception) { Errors.Add(exception.ToString()); }
    }

    public struct Vector3
    {
        public float x, y, z;
        public Vector3(float x, float y, float z) { this.x = x; this.y = y; this.z = z; }
        public static Vector3 zero { get { return new Vector3(0, 0, 0); } }
        public static Vector3 one { get { return new Vector3(1, 1, 1); } }
        public static Vector3 up { get { return new Vector3(0, 1, 0); } }
        public static Vector3 forward { get { return new Vector3(0, 0, 1); } }
        public float magnitude { get { return (float)Math.Sqrt(x * x + y * y + z * z); } }
        public Vector3 normalized { get { float m = magnitude; return m > 1e-5f ? new Vector3(x / m, y / m, z / m) : zero; } }
        public static Vector3 Cross(Vector3 a, Vector3 b) { return new Vector3(a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x); }
        public static float Dot(Vector3 a, Vector3 b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
        public static Vector3 operator *(Vector3 a, float d) { return new Vector3(a.x * d, a.y * d, a.z * d); }
        public static Vector3 operator +(Vector3 a, Vector3 b) { return new Vector3(a.x + b.x, a.y + b.y, a.z + b.z); }
        public static Vector3 operator -(Vector3 a, Vector3 b) { return new Vector3(a.x - b.x, a.y - b.y, a.z - b.z); }
        public override string ToString() { return "(" + x + ", " + y + ", " + z + ")"; }
    }

    public struct Quaternion
    {
        public float x, y, z, w;
        public Quaternion(float x, float y, float z, float w) { this.x = x; this.y = y; this.z = z; this.w = w; }
        public static Quaternion identity { get { return new Quaternion(0, 0, 0, 1); } }

        public static Quaternion operator *(Quaternion a, Quaternion b)
        {
            return new Quaternion(
                a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y,
                a.w * b.y + a.y * b.w + a.z * b.x - a.x * b.z,
                a.w * b.z + a.z * b.w + a.x * b.y - a.y * b.x,
                a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z);
        }

        public static Vector3 operator *(Quaternion q, Vector3 v)
        {
            var r = q * new Quaternion(v.x, v.y, v.z, 0) * Inverse(q);
            return new Vector3(r.x, r.y, r.z);
        }

        public static Quaternion Inverse(Quaternion q) { return new Quaternion(-q.x, -q.y, -q.z, q.w); }

        /// <summary>The shortest turn taking direction `from` to `to`.</summary>
        public static Quaternion FromToRotation(Vector3 fromDirection, Vector3 toDirection)
        {
            var a = fromDirection.normalized; var b = toDirection.normalized;
            float d = Vector3.Dot(a, b);
            if (d < -0.999999f)
            {
                var axis = Vector3.Cross(new Vector3(1, 0, 0), a);
                if (axis.magnitude < 1e-6f) axis = Vector3.Cross(new Vector3(0, 1, 0), a);
                return AngleAxis(180f, axis.normalized);
            }
            var c = Vector3.Cross(a, b);
            var q = new Quaternion(c.x, c.y, c.z, 1 + d);
            float n = (float)Math.Sqrt(q.x * q.x + q.y * q.y + q.z * q.z + q.w * q.w);
            return new Quaternion(q.x / n, q.y / n, q.z / n, q.w / n);
        }

        /// <summary>A rotation whose +Z looks along `forward` with +Y as near `up` (world +Y) as it can.</summary>
        public static Quaternion LookRotation(Vector3 forward)
        {
            var f = forward.normalized;
            var yaw = FromToRotation(new Vector3(0, 0, 1), new Vector3(f.x, 0, f.z).magnitude > 1e-6f ? new Vector3(f.x, 0, f.z) : new Vector3(0, 0, 1));
            var flat = yaw * new Vector3(0, 0, 1);
            return FromToRotation(flat, f) * yaw;
        }

        public static Quaternion AngleAxis(float angle, Vector3 axis)
        {
            double h = angle * Math.PI / 360.0, n = Math.Sqrt(axis.x * axis.x + axis.y * axis.y + axis.z * axis.z);
            double s = Math.Sin(h) / n;
            return new Quaternion((float)(axis.x * s), (float)(axis.y * s), (float)(axis.z * s), (float)Math.Cos(h));
        }

        public override string ToString() { return "(" + x + ", " + y + ", " + z + ", " + w + ")"; }
    }

    /// <summary>Position and rotation, local to an optional parent (no scale). Setting
    /// `parent` keeps the world pose, as Unity's does.</summary>
    public class Transform : Component
    {
        private Vector3 _localPosition;
        private Quaternion _localRotation = Quaternion.identity;
        private Vector3 _localScale = Vector3.one;
        public Vector3 localPosition { get { return _localPosition; } set { _localPosition = value; } }
        public Quaternion localRotation { get { return _localRotation; } set { _localRotation = value; } }
        public Vector3 localScale { get { return _localScale; } set { _localScale = value; } }   // kept, not applied (no scale here)
        private Transform _parent;
        private readonly List<Transform> _children = new List<Transform>();

        public Transform parent
        {
            get { return _parent; }
            set
            {
                Vector3 p = position; Quaternion q = rotation;
                if (_parent != null) _parent._children.Remove(this);
                _parent = value;
                if (value != null) value._children.Add(this);
                position = p; rotation = q;
            }
        }

        public Vector3 position
        {
            get { return _parent == null ? localPosition : _parent.TransformPoint(localPosition); }
            set { localPosition = _parent == null ? value : Quaternion.Inverse(_parent.rotation) * (value - _parent.position); }
        }

        public Quaternion rotation
        {
            get { return _parent == null ? localRotation : _parent.rotation * localRotation; }
            set { localRotation = _parent == null ? value : Quaternion.Inverse(_parent.rotation) * value; }
        }

        public void SetParent(Transform parent, bool worldPositionStays)
        {
            if (worldPositionStays) { this.parent = parent; return; }
            if (_parent != null) _parent._children.Remove(this);
            _parent = parent;
            if (parent != null) parent._children.Add(this);
        }

        public void LookAt(Vector3 worldPosition) { rotation = Quaternion.LookRotation(worldPosition - position); }

        public int childCount { get { return _children.Count; } }
        public Transform GetChild(int index) { return _children[index]; }
        internal List<Transform> Children { get { return _children; } }

        public Vector3 TransformPoint(Vector3 p) { return position + rotation * p; }
        public Vector3 InverseTransformPoint(Vector3 p) { return Quaternion.Inverse(rotation) * (p - position); }

        internal void Walk(List<Transform> into)
        {
            into.Add(this);
            foreach (var c in _children) c.Walk(into);
        }
    }
}

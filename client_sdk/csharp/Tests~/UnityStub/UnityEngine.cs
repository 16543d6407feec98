// A stand-in for the few UnityEngine types Runtime/Unity uses, so run.sh can compile
// the Unity layer and test its logic on Mono (UnityTests.cs). Same names and
// signatures as Unity's; the behaviour is the part the tests need (Quaternion's
// Hamilton product, a Transform hierarchy without scale, an Avatar's T-pose skeleton, XR devices the test sets up).
// Not shipped: Unity does not import Tests~.

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

        public T AddComponent<T>() where T : Component
        {
            var c = (T)Activator.CreateInstance(typeof(T), true);
            c.Attach(this);
            var mb = c as MonoBehaviour;
            if (mb != null) mb.CallAwake();
            return c;
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
            if (parent != null) copy.transform.SetParent(parent, false);
            foreach (var kv in map)
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
            copy.transform.localPosition = g.transform.localPosition;
            copy.transform.localRotation = g.transform.localRotation;
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
            c.Attach(into);
        }

        public T GetComponent<T>() { return _gameObject != null ? _gameObject.GetComponent<T>() : (this is T ? (T)(object)this : default(T)); }

        public T GetComponentInChildren<T>()
        {
            if (_gameObject != null) return _gameObject.GetComponentInChildren<T>();
            return this is T ? (T)(object)this : default(T);
        }

        public T[] GetComponentsInChildren<T>(bool includeInactive) where T : Component
        {
            var all = new List<Transform>();
            transform.Walk(all);
            var found = new List<T>();
            foreach (var t in all) if (t is T) found.Add((T)(Component)t);
            return found.ToArray();
        }
    }

    public class Behaviour : Component
    {
        public bool enabled = true;
    }

    /// <summary>Unity calls Awake when the component is added (AddComponent) or its
    /// GameObject instantiated; Start, Update, LateUpdate and OnDestroy by the player loop,
    /// which a test calls by hand (Loop).</summary>
    public class MonoBehaviour : Behaviour
    {
        internal void CallAwake() { Loop.Call(this, "Awake"); }
    }

    /// <summary>Test-only: Unity's player loop by hand (Unity calls these itself).</summary>
    public static class Loop
    {
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
        public Vector3 localPosition;
        public Quaternion localRotation = Quaternion.identity;
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

    public sealed class Avatar : Object
    {
        public bool isHuman;
        public HumanDescription humanDescription;  // Unity: a read-only property
    }

    public struct HumanDescription
    {
        public SkeletonBone[] skeleton;
    }

    /// <summary>A Transform's name and its T-pose in its parent's space (Unity's SkeletonBone).</summary>
    public struct SkeletonBone
    {
        public string name;
        public Vector3 position;
        public Quaternion rotation;
        public Vector3 scale;
    }

    public enum HumanBodyBones
    {
        Hips, LeftUpperLeg, RightUpperLeg, LeftLowerLeg, RightLowerLeg, LeftFoot, RightFoot, Spine, Chest, Neck, Head,
        LeftShoulder, RightShoulder, LeftUpperArm, RightUpperArm, LeftLowerArm, RightLowerArm, LeftHand, RightHand,
        LeftToes, RightToes, LeftEye, RightEye, Jaw, UpperChest = 54, LastBone = 55,
    }

    public class Animator : Behaviour
    {
        public Avatar avatar;
        public readonly Dictionary<HumanBodyBones, Transform> Bones = new Dictionary<HumanBodyBones, Transform>();
        public Transform GetBoneTransform(HumanBodyBones b) { Transform t; return Bones.TryGetValue(b, out t) ? t : null; }

        internal override void CopyTo(GameObject into, Dictionary<Transform, Transform> map)
        {
            var a = into.AddComponent<Animator>();
            a.avatar = avatar;
            foreach (var kv in Bones) a.Bones[kv.Key] = map[kv.Value];
        }
    }
}

namespace UnityEngine.XR
{
    public enum XRNode { LeftEye, RightEye, CenterEye, Head, LeftHand, RightHand, GameController, TrackingReference, HardwareTracker }

    [Flags]
    public enum TrackingOriginModeFlags { Unknown = 0, Device = 1, Floor = 2, TrackingReference = 4, Unbounded = 8 }

    public class XRInputSubsystem
    {
        public TrackingOriginModeFlags Mode = TrackingOriginModeFlags.Device;
        public TrackingOriginModeFlags Supported = TrackingOriginModeFlags.Device | TrackingOriginModeFlags.Floor;
        public TrackingOriginModeFlags GetTrackingOriginMode() { return Mode; }
        public TrackingOriginModeFlags GetSupportedTrackingOriginModes() { return Supported; }
        public bool TrySetTrackingOriginMode(TrackingOriginModeFlags origin)
        {
            if ((Supported & origin) == 0) return false;
            Mode = origin;
            return true;
        }
    }

    public struct InputFeatureUsage<T>
    {
        public string name;
        public InputFeatureUsage(string name) { this.name = name; }
    }

    public static class CommonUsages
    {
        public static readonly InputFeatureUsage<bool> isTracked = new InputFeatureUsage<bool>("IsTracked");
        public static readonly InputFeatureUsage<Vector3> devicePosition = new InputFeatureUsage<Vector3>("DevicePosition");
        public static readonly InputFeatureUsage<Quaternion> deviceRotation = new InputFeatureUsage<Quaternion>("DeviceRotation");
    }

    /// <summary>A test device: its features by usage name; absent: TryGetFeatureValue fails.</summary>
    public sealed class FakeDevice
    {
        public XRInputSubsystem Subsystem;
        public readonly Dictionary<string, object> Features = new Dictionary<string, object>();
    }

    public struct InputDevice
    {
        internal FakeDevice Fake;
        public bool isValid { get { return Fake != null; } }
        public XRInputSubsystem subsystem { get { return Fake == null ? null : Fake.Subsystem; } }

        private bool Get<T>(string name, out T value)
        {
            object o;
            if (Fake != null && Fake.Features.TryGetValue(name, out o)) { value = (T)o; return true; }
            value = default(T);
            return false;
        }

        public bool TryGetFeatureValue(InputFeatureUsage<bool> usage, out bool value) { return Get(usage.name, out value); }
        public bool TryGetFeatureValue(InputFeatureUsage<Vector3> usage, out Vector3 value) { return Get(usage.name, out value); }
        public bool TryGetFeatureValue(InputFeatureUsage<Quaternion> usage, out Quaternion value) { return Get(usage.name, out value); }
    }

    public static class InputDevices
    {
        public static readonly Dictionary<XRNode, FakeDevice> Fakes = new Dictionary<XRNode, FakeDevice>();
        public static InputDevice GetDeviceAtXRNode(XRNode node)
        {
            FakeDevice d;
            return new InputDevice { Fake = Fakes.TryGetValue(node, out d) ? d : null };
        }
    }
}

// The stand-in's UnityEngine.Events (see API.md): UnityEvent with 0, 1 and 2 arguments,
// runtime listeners only (a persistent listener is the editor's; it is called the same way).

using System;
using System.Collections.Generic;

namespace UnityEngine.Events
{
    public delegate void UnityAction();
    public delegate void UnityAction<T0>(T0 arg0);
    public delegate void UnityAction<T0, T1>(T0 arg0, T1 arg1);

    [Serializable]
    public abstract class UnityEventBase
    {
        public int GetPersistentEventCount() { return 0; }
        public void RemoveAllListeners() { Clear(); }
        internal abstract void Clear();
    }

    [Serializable]
    public class UnityEvent : UnityEventBase
    {
        private readonly List<UnityAction> _calls = new List<UnityAction>();
        public void AddListener(UnityAction call) { _calls.Add(call); }
        public void RemoveListener(UnityAction call) { _calls.Remove(call); }
        public void Invoke() { foreach (var c in _calls.ToArray()) c(); }
        internal override void Clear() { _calls.Clear(); }
    }

    [Serializable]
    public class UnityEvent<T0> : UnityEventBase
    {
        private readonly List<UnityAction<T0>> _calls = new List<UnityAction<T0>>();
        public void AddListener(UnityAction<T0> call) { _calls.Add(call); }
        public void RemoveListener(UnityAction<T0> call) { _calls.Remove(call); }
        public void Invoke(T0 arg0) { foreach (var c in _calls.ToArray()) c(arg0); }
        internal override void Clear() { _calls.Clear(); }
    }

    [Serializable]
    public class UnityEvent<T0, T1> : UnityEventBase
    {
        private readonly List<UnityAction<T0, T1>> _calls = new List<UnityAction<T0, T1>>();
        public void AddListener(UnityAction<T0, T1> call) { _calls.Add(call); }
        public void RemoveListener(UnityAction<T0, T1> call) { _calls.Remove(call); }
        public void Invoke(T0 arg0, T1 arg1) { foreach (var c in _calls.ToArray()) c(arg0, arg1); }
        internal override void Clear() { _calls.Clear(); }
    }
}

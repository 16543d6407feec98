// Unity-only: the UnityEvent types PosecastAvatarManager raises, concrete so the
// inspector can list their listeners (a serialized field needs a non-generic type on
// older Unity versions).

using System;
using UnityEngine.Events;

namespace Posecast.Client.Unity
{
    /// <summary>A player id: Joined (this client's own, at each join and rejoin), PlayerJoined, PlayerLeft.</summary>
    [Serializable] public sealed class PosecastPlayerEvent : UnityEvent<string> { }

    /// <summary>An error: its code (the wire code of proto/errors.json, such as ROOM_FULL, or for an
    /// error of the connection itself the exception's type name, such as ConnectFailedException) and its message.</summary>
    [Serializable] public sealed class PosecastErrorEvent : UnityEvent<string, string> { }

    /// <summary>A lost connection being retried: the attempt (1 for the first) and the wait before it, seconds.</summary>
    [Serializable] public sealed class PosecastReconnectingEvent : UnityEvent<int, float> { }
}

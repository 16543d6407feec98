// The events a PosecastClient hands to the application: a bounded queue (past
// ClientOptions.MaxEvents the oldest is dropped, counted in Stats.EventsDropped) that
// the receive task fills and a Unity Update drains with TryGet, or a task awaits with
// NextAsync; and the error that ended the session, thrown once the queue is empty.

using System;
using System.Collections.Generic;
using System.Threading;
using System.Threading.Tasks;

namespace Posecast.Client
{
    internal sealed class EventQueue
    {
        private readonly Queue<ClientEvent> _events = new Queue<ClientEvent>();
        private readonly SemaphoreSlim _wake = new SemaphoreSlim(0, int.MaxValue);
        private readonly ClientOptions _options;
        private readonly Stats _stats;
        private Exception _failure;

        public EventQueue(ClientOptions options, Stats stats)
        {
            _options = options;
            _stats = stats;
        }

        /// <summary>The error that ended the session; null while it goes on.</summary>
        public Exception Failure { get { return _failure; } }

        public void Push(ClientEvent e)
        {
            lock (_events)
            {
                if (_events.Count >= _options.MaxEvents) { _events.Dequeue(); _stats.EventsDropped++; }
                _events.Enqueue(e);
            }
            _wake.Release();
        }

        /// <summary>End the session with `cause`: TryGet throws it once the queue is empty.</summary>
        public void Fail(Exception cause)
        {
            _failure = cause;
            _wake.Release();
        }

        /// <summary>Wake a waiting NextAsync (the client is closing).</summary>
        public void Wake() { _wake.Release(); }

        /// <summary>The next event if one is waiting. Throws the error that ended the session.</summary>
        public bool TryGet(out ClientEvent e)
        {
            lock (_events)
            {
                if (_events.Count > 0) { e = _events.Dequeue(); return true; }
            }
            e = null;
            if (_failure != null) throw _failure;
            return false;
        }

        /// <summary>The next event, waiting for it; null once `closing` or `ct` is cancelled.</summary>
        public async Task<ClientEvent> NextAsync(CancellationToken closing, CancellationToken ct)
        {
            while (true)
            {
                ClientEvent e;
                if (TryGet(out e)) return e;
                if (closing.IsCancellationRequested || ct.IsCancellationRequested) return null;
                try { await _wake.WaitAsync(250, ct).ConfigureAwait(false); }
                catch (OperationCanceledException) { return null; }
            }
        }
    }
}

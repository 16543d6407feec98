/* The thread pool every kernel call runs on.
 *
 * The work of one call is cut into tiles of PC_TILE rows that the calling thread and
 * threads - 1 pthread workers take from one atomic counter: one pool for the whole
 * tick, nothing else spins. Workers sleep on a condition variable between calls; a
 * forked child starts its own on its first call. pool_stats counts the tiles each
 * thread ran.
 */
#include "pc_module.h"

#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>

#define MAX_THREADS 64

static struct {
    pthread_mutex_t mu;
    pthread_cond_t work, done;
    pthread_mutex_t call; /* one parallel call at a time */
    int threads, started;
    unsigned long generation;
    int busy;   /* workers still on this generation */
    int active; /* threads that take tiles in this generation (the caller is 0) */
    int stop;
    int respawn; /* set in a forked child: start the workers again on the next call */
    PcTileFn fn;
    void *ctx;
    int64_t rows, tiles;
    int64_t next; /* atomic */
    float *scratch[MAX_THREADS];
    pthread_t tid[MAX_THREADS];
} P = {PTHREAD_MUTEX_INITIALIZER, PTHREAD_COND_INITIALIZER, PTHREAD_COND_INITIALIZER,
       PTHREAD_MUTEX_INITIALIZER, 1, 1, 0, 0, 1, 0, 0, NULL, NULL, 0, 0, 0, {0}, {0}};

static int64_t tiles_by[MAX_THREADS]; /* tiles each thread ran (pool_stats) */

static void run_tiles(int me) {
    float *scratch = P.scratch[me];
    for (;;) {
        int64_t t = __atomic_fetch_add(&P.next, 1, __ATOMIC_RELAXED);
        if (t >= P.tiles) return;
        __atomic_fetch_add(&tiles_by[me], 1, __ATOMIC_RELAXED);
        int64_t r0 = t * PC_TILE, r1 = r0 + PC_TILE;
        P.fn(P.ctx, r0, r1 < P.rows ? r1 : P.rows, scratch);
    }
}

static void *worker(void *arg) {
    int me = (int)(intptr_t)arg;
    unsigned long seen = 0;
    pthread_mutex_lock(&P.mu);
    for (;;) {
        while (!P.stop && P.generation == seen) pthread_cond_wait(&P.work, &P.mu);
        if (P.stop) break;
        seen = P.generation;
        int active = P.active;
        pthread_mutex_unlock(&P.mu);
        if (me < active) run_tiles(me);
        pthread_mutex_lock(&P.mu);
        if (--P.busy == 0) pthread_cond_signal(&P.done);
    }
    pthread_mutex_unlock(&P.mu);
    return NULL;
}

static float *alloc_scratch(void) {
    void *p = NULL;
    if (posix_memalign(&p, PC_ALIGN, PC_SCRATCH_BYTES) != 0) return NULL;
    return (float *)p;
}

/* A forked child has only the thread that forked: forget the workers, so its first
 * parallel call starts new ones instead of waiting for threads that do not exist. */
static void after_fork_child(void) {
    pthread_mutex_init(&P.mu, NULL);
    pthread_mutex_init(&P.call, NULL);
    pthread_cond_init(&P.work, NULL);
    pthread_cond_init(&P.done, NULL);
    P.started = 1, P.busy = 0, P.generation = 0, P.stop = 0; /* scratch blocks are reused */
    P.respawn = P.threads > 1;
}

static int ensure_threads(int n) {
    if (!P.scratch[0] && !(P.scratch[0] = alloc_scratch())) return -1;
    while (P.started < n) {
        int i = P.started;
        if (!P.scratch[i] && !(P.scratch[i] = alloc_scratch())) return -1;
        if (pthread_create(&P.tid[i], NULL, worker, (void *)(intptr_t)i) != 0) return -1;
        P.started++;
    }
    return 0;
}

void pc_parallel_rows(PcTileFn fn, void *ctx, int64_t rows) {
    pthread_mutex_lock(&P.call);
    if (P.respawn) {
        P.respawn = 0;
        if (ensure_threads(P.threads) != 0) P.threads = P.started; /* fewer workers, still correct */
    }
    int64_t tiles = (rows + PC_TILE - 1) / PC_TILE;
    int helpers = P.threads - 1;
    if (helpers > tiles - 1) helpers = (int)(tiles > 0 ? tiles - 1 : 0);
    if (helpers > P.started - 1) helpers = P.started - 1;
    P.fn = fn, P.ctx = ctx, P.rows = rows, P.tiles = tiles;
    __atomic_store_n(&P.next, 0, __ATOMIC_RELAXED);
    if (helpers > 0) {
        pthread_mutex_lock(&P.mu);
        /* every started worker wakes and counts down; the first `helpers` take tiles */
        P.busy = P.started - 1;
        P.active = helpers + 1;
        P.generation++;
        pthread_cond_broadcast(&P.work);
        pthread_mutex_unlock(&P.mu);
    }
    run_tiles(0);
    if (helpers > 0) {
        pthread_mutex_lock(&P.mu);
        while (P.busy > 0) pthread_cond_wait(&P.done, &P.mu);
        pthread_mutex_unlock(&P.mu);
    }
    pthread_mutex_unlock(&P.call);
}

int pc_threads_init(void) {
    if (ensure_threads(1) != 0) {
        PyErr_NoMemory();
        return -1;
    }
    pthread_atfork(NULL, NULL, after_fork_child);
    return 0;
}

/* --- the Python functions ------------------------------------------------------------ */

static PyObject *py_set_threads(PyObject *self, PyObject *arg) {
    long n = PyLong_AsLong(arg);
    if (n == -1 && PyErr_Occurred()) return NULL;
    if (n < 1 || n > MAX_THREADS) return PyErr_Format(PyExc_ValueError, "threads must be 1..%d", MAX_THREADS);
    pthread_mutex_lock(&P.call);
    int rc = ensure_threads((int)n);
    if (rc == 0) P.threads = (int)n;
    pthread_mutex_unlock(&P.call);
    if (rc != 0) return PyErr_NoMemory();
    Py_RETURN_NONE;
}

static PyObject *py_threads(PyObject *self, PyObject *noargs) { return PyLong_FromLong(P.threads); }

static PyObject *py_pool_stats(PyObject *self, PyObject *noargs) {
    PyObject *out = PyTuple_New(P.started);
    for (int i = 0; out && i < P.started; i++)
        PyTuple_SET_ITEM(out, i, PyLong_FromLongLong(__atomic_load_n(&tiles_by[i], __ATOMIC_RELAXED)));
    return out;
}

PyMethodDef pc_threads_methods[] = {
    {"set_threads", py_set_threads, METH_O, "Threads for the kernels (the caller is one)."},
    {"threads", py_threads, METH_NOARGS, "Threads the kernels use."},
    {"pool_stats", py_pool_stats, METH_NOARGS, "Tiles each pool thread has run (the caller first)."},
    {NULL, NULL, 0, NULL},
};

/* posecast._native: the SSI kernels as a CPython extension.
 *
 * Arrays come in through the buffer protocol (numpy arrays, no numpy headers), the
 * GIL is released while the kernels run, and the work of one call is cut into
 * tiles of PC_TILE rows that the calling thread and the pool's workers take from one
 * atomic counter: one thread pool for the whole tick, nothing else spins.
 *
 * Instruction-set dispatch happens once at import (and on set_isa): the best level
 * this CPU supports among avx512bf16, avx512f, avx2, generic, capped by the
 * environment variable POSECAST_NATIVE_ISA. The GRU gates' precision is a setting of
 * its own (set_precision, POSECAST_NATIVE_PRECISION): bf16 by default on the
 * avx512bf16 level, fp32 on the others. See docs/engine.md.
 */
#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include <pthread.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include "pc_kernels.h"
#include "pc_records.h"
#include "pc_upper.h"

/* --- levels ---------------------------------------------------------------------- */

typedef struct {
    const char *name;
    const PcKernels *k;
    int (*supported)(void);
} Level;

#if defined(__x86_64__) || defined(_M_X64)
static int has_avx512bf16(void) {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
           __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl") &&
           __builtin_cpu_supports("avx512bf16");
}
static int has_avx512(void) {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
           __builtin_cpu_supports("avx512dq") && __builtin_cpu_supports("avx512vl");
}
static int has_avx2(void) {
    __builtin_cpu_init();
    return __builtin_cpu_supports("avx2") && __builtin_cpu_supports("fma");
}
#endif
static int always(void) { return 1; }

static const Level LEVELS[] = {
#if defined(__x86_64__) || defined(_M_X64)
    {"avx512bf16", &pc_kernels_avx512bf16, has_avx512bf16},
    {"avx512f", &pc_kernels_avx512, has_avx512},
    {"avx2", &pc_kernels_avx2, has_avx2},
#endif
    {"generic", &pc_kernels_generic, always},
};
#define N_LEVELS ((int)(sizeof(LEVELS) / sizeof(LEVELS[0])))

static int g_level = N_LEVELS - 1;
/* The GRU gates' arithmetic, separate from the level: 1 bf16 (on the level's
 * instructions where it has them, avx512bf16, else the same arithmetic in plain vector
 * code), 0 fp32. */
static int g_bf16 = 0;

static int level_index(const char *name) {
    for (int i = 0; i < N_LEVELS; i++)
        if (strcmp(LEVELS[i].name, name) == 0) return i;
    return -1;
}

/* The best supported level at or below `cap` (an index; 0 is the best). */
static int best_level(int cap) {
    for (int i = cap; i < N_LEVELS; i++)
        if (LEVELS[i].supported()) return i;
    return N_LEVELS - 1;
}

/* --- the thread pool -------------------------------------------------------------- */

typedef void (*TileFn)(void *ctx, int64_t r0, int64_t r1, float *scratch);

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
    TileFn fn;
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

static void parallel_rows(TileFn fn, void *ctx, int64_t rows) {
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

/* --- buffers ---------------------------------------------------------------------- */

typedef struct {
    Py_buffer view;
    int held;
} Buf;

/* Get a C-contiguous buffer of `count` items of `itemsize` bytes whose format is one
 * of `formats` (struct-module codes); count < 0 accepts any length. */
static int get_buf(PyObject *obj, Buf *b, const char *what, const char *formats, Py_ssize_t itemsize,
                   Py_ssize_t count, int writable) {
    b->held = 0;
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    if (PyObject_GetBuffer(obj, &b->view, flags) != 0) {
        PyErr_Format(PyExc_ValueError, "%s: needs a C-contiguous%s array", what,
                     writable ? " writable" : "");
        return -1;
    }
    b->held = 1;
    const char *fmt = b->view.format ? b->view.format : "B";
    if (*fmt == '<' || *fmt == '=' || *fmt == '@') fmt++;
    if (b->view.itemsize != itemsize || strlen(fmt) != 1 || !strchr(formats, fmt[0])) {
        PyErr_Format(PyExc_ValueError, "%s: wrong dtype (format %s, itemsize %zd)", what, fmt,
                     b->view.itemsize);
        return -1;
    }
    if (count >= 0 && b->view.len != count * itemsize) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd items, got %zd", what, count,
                     b->view.len / itemsize);
        return -1;
    }
    return 0;
}

static void release(Buf *bufs, int n) {
    for (int i = 0; i < n; i++)
        if (bufs[i].held) PyBuffer_Release(&bufs[i].view);
}

#define F32 "f", 4
#define F64 "d", 8
#define I64 "lq", 8
#define BOOL "?B", 1

/* --- packed weights ---------------------------------------------------------------- */

typedef struct {
    PcDecoder d;
    void *mem;
} DecoderBox;

typedef struct {
    PcPool p;
    void *mem;
} PoolBox;

static void free_decoder(PyObject *cap) {
    DecoderBox *b = PyCapsule_GetPointer(cap, "posecast.decoder");
    if (b) {
        free(b->mem);
        free(b);
    }
}

static void free_pool(PyObject *cap) {
    PoolBox *b = PyCapsule_GetPointer(cap, "posecast.pool");
    if (b) {
        free(b->mem);
        free(b);
    }
}

/* An arena of 64-byte aligned float blocks. */
typedef struct {
    char *base;
    size_t used, size;
} Arena;

static float *take(Arena *a, size_t floats) {
    size_t bytes = (floats * 4 + PC_ALIGN - 1) / PC_ALIGN * PC_ALIGN;
    float *p = (float *)(a->base + a->used);
    a->used += bytes;
    memset(p, 0, bytes);
    return p;
}

/* (K, N) float32 -> (K/2, N) pairs: low half row 2k, high half row 2k + 1. */
static void pack_pairs(const float *w, int K, int N, uint32_t *out) {
    for (int k = 0; k < K / 2; k++)
        for (int n = 0; n < N; n++)
            out[(size_t)k * N + n] =
                pc_bf16_bits(w[(size_t)(2 * k) * N + n]) | (pc_bf16_bits(w[(size_t)(2 * k + 1) * N + n]) << 16);
}

static PyObject *py_pack_decoder(PyObject *self, PyObject *args) {
    int F, H, n_rot, n_root, use_bf16;
    PyObject *o[10];
    if (!PyArg_ParseTuple(args, "iiiiOOOOOOOOOOp", &F, &H, &n_rot, &n_root, &o[0], &o[1], &o[2],
                          &o[3], &o[4], &o[5], &o[6], &o[7], &o[8], &o[9], &use_bf16))
        return NULL;
    if (F < 1 || F > 512 || H < 64 || H > 256 || H % 64 || n_rot != 108 || (n_root != 0 && n_root != 9)) {
        PyErr_SetString(PyExc_ValueError, "unsupported decoder shape");
        return NULL;
    }
    const int K = n_rot + n_root + 2;
    Buf b[10];
    memset(b, 0, sizeof(b));
    const char *names[10] = {"mean", "inv_std", "wx", "bfc", "wih", "bih", "whh", "bhh", "whead", "bhead"};
    const Py_ssize_t counts[10] = {F, F, (Py_ssize_t)F * H, H, (Py_ssize_t)H * 3 * H, 3 * H,
                                   (Py_ssize_t)H * 3 * H, 3 * H, (Py_ssize_t)H * K, K};
    for (int i = 0; i < 10; i++)
        if (get_buf(o[i], &b[i], names[i], F32, counts[i], 0) != 0) {
            release(b, 10);
            return NULL;
        }
    size_t floats = 2 * F + F * H + H + 2 * 3 * H * H + 2 * 3 * H + H * PC_HEADW + PC_HEADW +
                    3 * H * H /* bf16 pairs: 2 x (H/2 x 3H) uint32 */ + 16 * 64;
    DecoderBox *box = calloc(1, sizeof(DecoderBox));
    void *mem = NULL;
    if (!box || posix_memalign(&mem, PC_ALIGN, floats * 4 + 64 * PC_ALIGN) != 0) {
        free(box);
        release(b, 10);
        return PyErr_NoMemory();
    }
    Arena ar = {mem, 0, floats * 4 + 64 * PC_ALIGN};
    PcDecoder *d = &box->d;
    box->mem = mem;
    d->F = F, d->H = H, d->n_rot = n_rot, d->n_root = n_root, d->bf16 = use_bf16;
    d->mean = take(&ar, F), d->inv_std = take(&ar, F), d->wx = take(&ar, (size_t)F * H);
    d->bfc = take(&ar, H);
    d->wih = take(&ar, (size_t)3 * H * H), d->whh = take(&ar, (size_t)3 * H * H);
    d->bih = take(&ar, 3 * H), d->bhh = take(&ar, 3 * H);
    d->whead = take(&ar, (size_t)H * PC_HEADW), d->bhead = take(&ar, PC_HEADW);
    d->wih_bf = (uint32_t *)take(&ar, (size_t)3 * H * H / 2);
    d->whh_bf = (uint32_t *)take(&ar, (size_t)3 * H * H / 2);
    float *dst[8] = {d->mean, d->inv_std, d->wx, d->bfc, d->wih, d->bih, d->whh, d->bhh};
    for (int i = 0; i < 8; i++) memcpy(dst[i], b[i].view.buf, counts[i] * 4);
    const float *wh = b[8].view.buf, *bh = b[9].view.buf;
    for (int k = 0; k < H; k++) memcpy(d->whead + (size_t)k * PC_HEADW, wh + (size_t)k * K, K * 4);
    memcpy(d->bhead, bh, K * 4);
    pack_pairs(d->wih, H, 3 * H, d->wih_bf);
    pack_pairs(d->whh, H, 3 * H, d->whh_bf);
    release(b, 10);
    return PyCapsule_New(box, "posecast.decoder", free_decoder);
}

static PyObject *py_pack_pool(PyObject *self, PyObject *args) {
    PyObject *o_off, *o_mean, *o_std, *layers;
    if (!PyArg_ParseTuple(args, "OOOO", &o_off, &o_mean, &o_std, &layers)) return NULL;
    if (!PyList_Check(layers) || PyList_GET_SIZE(layers) != PC_AE_LAYERS) {
        PyErr_Format(PyExc_ValueError, "layers: a list of %d (w, b) pairs", PC_AE_LAYERS);
        return NULL;
    }
    Buf b[3];
    memset(b, 0, sizeof(b));
    if (get_buf(o_off, &b[0], "offsets", F32, PC_J * 3, 0) || get_buf(o_mean, &b[1], "mean", F32, PC_J * 3, 0) ||
        get_buf(o_std, &b[2], "inv_std", F32, PC_J * 3, 0)) {
        release(b, 3);
        return NULL;
    }
    PoolBox *box = calloc(1, sizeof(PoolBox));
    size_t bytes = (size_t)PC_AE_LAYERS * (PC_AE_MAXW * PC_AE_MAXW + PC_AE_MAXW) * 4 + 64 * PC_ALIGN;
    void *mem = NULL;
    if (!box || posix_memalign(&mem, PC_ALIGN, bytes) != 0) {
        free(box);
        release(b, 3);
        return PyErr_NoMemory();
    }
    box->mem = mem;
    Arena ar = {mem, 0, bytes};
    PcPool *p = &box->p;
    memcpy(p->offsets, b[0].view.buf, sizeof(p->offsets));
    memcpy(p->mean, b[1].view.buf, sizeof(p->mean));
    memcpy(p->inv_std, b[2].view.buf, sizeof(p->inv_std));
    release(b, 3);
    int k_expect = PC_J * 3;
    for (int l = 0; l < PC_AE_LAYERS; l++) {
        PyObject *pair = PyList_GET_ITEM(layers, l);
        PyObject *ow, *ob;
        int k, n;
        if (!PyArg_ParseTuple(pair, "iiOO", &k, &n, &ow, &ob)) goto fail;
        int last = l == PC_AE_LAYERS - 1;
        if (k != k_expect || n < 1 || n > PC_AE_MAXW || (last && n != 108)) {
            PyErr_Format(PyExc_ValueError, "layer %d: unsupported shape (%d, %d)", l, k, n);
            goto fail;
        }
        Buf lb[2];
        memset(lb, 0, sizeof(lb));
        if (get_buf(ow, &lb[0], "layer weight", F32, (Py_ssize_t)k * n, 0) ||
            get_buf(ob, &lb[1], "layer bias", F32, n, 0)) {
            release(lb, 2);
            goto fail;
        }
        PcLayer *L = &p->layers[l];
        L->k = k, L->n = n, L->np = (n + 63) / 64 * 64;
        L->w = take(&ar, (size_t)k * L->np), L->b = take(&ar, L->np);
        const float *w = lb[0].view.buf;
        for (int i = 0; i < k; i++) memcpy(L->w + (size_t)i * L->np, w + (size_t)i * n, n * 4);
        memcpy(L->b, lb[1].view.buf, n * 4);
        release(lb, 2);
        k_expect = n;
    }
    return PyCapsule_New(box, "posecast.pool", free_pool);
fail:
    free(box->mem);
    free(box);
    return NULL;
}

/* --- the calls ------------------------------------------------------------------- */

typedef struct {
    const PcKernels *k;
    const PcDecoder *d;
    PcDecodeArgs a;
} DecodeCtx;

static void decode_fn(void *ctx, int64_t r0, int64_t r1, float *scratch) {
    DecodeCtx *c = ctx;
    c->k->decode(c->d, &c->a, r0, r1, scratch);
}

static PyObject *py_decode(PyObject *self, PyObject *args) {
    PyObject *cap, *o[8];
    Py_ssize_t group;
    if (!PyArg_ParseTuple(args, "OOnOOOOOO", &cap, &o[0], &group, &o[1], &o[2], &o[3], &o[4], &o[5],
                          &o[6]))
        return NULL;
    DecoderBox *box = PyCapsule_GetPointer(cap, "posecast.decoder");
    if (!box) return NULL;
    const PcDecoder *d = &box->d;
    Buf b[7];
    memset(b, 0, sizeof(b));
    if (group < 1) {
        PyErr_SetString(PyExc_ValueError, "group must be >= 1");
        return NULL;
    }
    if (get_buf(o[0], &b[0], "features", F32, -1, 0)) goto fail;
    Py_ssize_t G = b[0].view.len / 4 / d->F, R = G * group;
    if (G * d->F * 4 != b[0].view.len) {
        PyErr_SetString(PyExc_ValueError, "features: not (G, F)");
        goto fail;
    }
    if (get_buf(o[1], &b[1], "cache", F32, R * d->H, 0) || get_buf(o[2], &b[2], "h", F32, R * d->H, 0) ||
        get_buf(o[3], &b[3], "rotations", F32, R * d->n_rot, 1) ||
        get_buf(o[5], &b[5], "contacts", F32, R * 2, 1) || get_buf(o[6], &b[6], "h_out", F32, R * d->H, 1))
        goto fail;
    if (d->n_root) {
        if (o[4] == Py_None) {
            PyErr_SetString(PyExc_ValueError, "root: this model predicts the pelvis");
            goto fail;
        }
        if (get_buf(o[4], &b[4], "root", F32, R * d->n_root, 1)) goto fail;
    }
    float *xproj = NULL;
    if (G > 0 && posix_memalign((void **)&xproj, PC_ALIGN, (size_t)G * d->H * 4) != 0) {
        PyErr_NoMemory();
        goto fail;
    }
    DecodeCtx c = {LEVELS[g_level].k, d, {xproj, group, b[1].view.buf, b[2].view.buf, b[3].view.buf,
                                          d->n_root ? b[4].view.buf : NULL, b[5].view.buf, b[6].view.buf,
                                          g_bf16}};
    const float *x = b[0].view.buf;
    Py_BEGIN_ALLOW_THREADS;
    for (Py_ssize_t g = 0; g < G; g++) { /* the tracker part, once per group */
        float xn[512];
        const float *xg = x + g * d->F;
        for (int i = 0; i < d->F && i < 512; i++) xn[i] = (xg[i] - d->mean[i]) * d->inv_std[i];
        float *out = xproj + g * d->H;
        memcpy(out, d->bfc, d->H * 4);
        for (int i = 0; i < d->F; i++)
            for (int h = 0; h < d->H; h++) out[h] += xn[i] * d->wx[(size_t)i * d->H + h];
    }
    if (R > 0) parallel_rows(decode_fn, &c, R);
    Py_END_ALLOW_THREADS;
    free(xproj);
    release(b, 7);
    Py_RETURN_NONE;
fail:
    release(b, 7);
    return NULL;
}

typedef struct {
    const PcKernels *k;
    const PcPool *p;
    PcPoolArgs a;
} PoolCtx;

static void pool_fn(void *ctx, int64_t r0, int64_t r1, float *scratch) {
    PoolCtx *c = ctx;
    c->k->pool(c->p, &c->a, r0, r1, scratch);
}

static void emit_fn(void *ctx, int64_t r0, int64_t r1, float *scratch) {
    PoolCtx *c = ctx;
    c->k->emit(c->p, &c->a, r0, r1, scratch);
}

/* The buffers pool and emit share, o[1..9] into b[1..9] (b[0], the rotations, is read
 * first, for R): contacts, the G pelvis poses, the four contact-IK state arrays, the
 * world positions out, and the last output (emit: world rotations, pool: scores).
 * Returns the call's PcPoolArgs in *a, or -1 with the error set. */
static int get_pool_bufs(PyObject **o, Buf *b, Py_ssize_t R, Py_ssize_t group, int release_frames,
                         double max_drift, int emit, PcPoolArgs *a) {
    Py_ssize_t G = R / group;
    if (get_buf(o[1], &b[1], "contacts", F32, R * 2, 0) || get_buf(o[2], &b[2], "root_mat", F32, G * 9, 0) ||
        get_buf(o[3], &b[3], "root_pos", F32, G * 3, 0) || get_buf(o[4], &b[4], "locked", BOOL, R * 2, 1) ||
        get_buf(o[5], &b[5], "lock_pos", F64, R * 6, 1) || get_buf(o[6], &b[6], "release", I64, R * 2, 1) ||
        get_buf(o[7], &b[7], "suppressed", BOOL, R * 2, 1) ||
        get_buf(o[8], &b[8], emit ? "positions" : "world_out", F32, R * 57, 1) ||
        (emit ? get_buf(o[9], &b[9], "rotations_out", F32, R * 76, 1)
              : get_buf(o[9], &b[9], "scores", F64, R, 1)))
        return -1;
    PcPoolArgs args = {b[0].view.buf, b[1].view.buf, b[2].view.buf, b[3].view.buf, group, b[4].view.buf,
                       b[7].view.buf, b[5].view.buf, b[6].view.buf, release_frames, max_drift, b[8].view.buf,
                       emit ? NULL : b[9].view.buf, emit ? b[9].view.buf : NULL};
    *a = args;
    return 0;
}

/* The rotations (R, 108) in b[0]; R, or -1 with the error set. */
static Py_ssize_t get_rotations(PyObject *o, Buf *b, Py_ssize_t group) {
    if (get_buf(o, b, "rotations", F32, -1, 0)) return -1;
    Py_ssize_t R = b->view.len / 4 / 108;
    if (R * 108 * 4 != b->view.len || R % group) {
        PyErr_SetString(PyExc_ValueError, "rotations: not (R, 108) with R a multiple of group");
        return -1;
    }
    return R;
}

static PyObject *run_pool(PyObject *cap, PyObject **o, Py_ssize_t group, int release_frames, double max_drift,
                          int emit) {
    PoolBox *box = PyCapsule_GetPointer(cap, "posecast.pool");
    if (!box) return NULL;
    if (group < 1) {
        PyErr_SetString(PyExc_ValueError, "group must be >= 1");
        return NULL;
    }
    Buf b[10];
    memset(b, 0, sizeof(b));
    PoolCtx c = {LEVELS[g_level].k, &box->p, {0}};
    Py_ssize_t R = get_rotations(o[0], &b[0], group);
    if (R < 0 || get_pool_bufs(o, b, R, group, release_frames, max_drift, emit, &c.a)) {
        release(b, 10);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS;
    if (R > 0) parallel_rows(emit ? emit_fn : pool_fn, &c, R);
    Py_END_ALLOW_THREADS;
    release(b, 10);
    Py_RETURN_NONE;
}

static PyObject *py_emit(PyObject *self, PyObject *args) {
    PyObject *cap, *o[10];
    int release_frames;
    double max_drift;
    if (!PyArg_ParseTuple(args, "OOOOOOOOOidOO", &cap, &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6],
                          &o[7], &release_frames, &max_drift, &o[8], &o[9]))
        return NULL;
    return run_pool(cap, o, 1, release_frames, max_drift, 1);
}

static PyObject *py_pool(PyObject *self, PyObject *args) {
    PyObject *cap, *o[10];
    Py_ssize_t group;
    int release_frames;
    double max_drift;
    if (!PyArg_ParseTuple(args, "OOOOOnOOOOidOO", &cap, &o[0], &o[1], &o[2], &o[3], &group, &o[4], &o[5],
                          &o[6], &o[7], &release_frames, &max_drift, &o[8], &o[9]))
        return NULL;
    return run_pool(cap, o, group, release_frames, max_drift, 0);
}

/* --- the shown pose's passes ------------------------------------------------------- */

/* The shown poses' positions (E, 19, 3) float32 in b; E, or -1 with the error set. */
static Py_ssize_t get_poses(PyObject *o, Buf *b) {
    if (get_buf(o, b, "positions", F32, -1, 0)) return -1;
    Py_ssize_t E = b->view.len / 4 / 57;
    if (E * 57 * 4 != b->view.len) {
        PyErr_SetString(PyExc_ValueError, "positions: not (E, 19, 3)");
        return -1;
    }
    return E;
}

static PyObject *py_upper_body(PyObject *self, PyObject *args) {
    PyObject *o[9], *free_obj;
    PcUpperArgs a;
    if (!PyArg_ParseTuple(args, "OOOOOdddddOOOO", &o[0], &o[1], &o[2], &o[3], &free_obj, &a.wrist_share,
                          &a.lean_share, &a.neck_share, &a.spine_reach, &a.reach_tol, &o[4], &o[5], &o[6],
                          &o[7]))
        return NULL;
    Buf b[9];
    memset(b, 0, sizeof(b));
    Py_ssize_t E = get_poses(o[0], &b[0]);
    if (E < 0) goto fail;
    if (get_buf(o[1], &b[1], "rotations", F32, E * 76, 0) || get_buf(o[2], &b[2], "tracker_pos", F64, -1, 0))
        goto fail;
    a.slots = E ? b[2].view.len / 8 / 3 / E : 3;
    if (a.slots < 3 || a.slots * 3 * E * 8 != b[2].view.len) {
        PyErr_SetString(PyExc_ValueError, "tracker_pos: not (E, slots >= 3, 3)");
        goto fail;
    }
    if (get_buf(o[3], &b[3], "tracker_quat", F64, E * a.slots * 4, 0) ||
        (free_obj != Py_None && get_buf(free_obj, &b[8], "free_root", BOOL, E, 0)) ||
        get_buf(o[4], &b[4], "offsets", F64, 57, 0) || get_buf(o[5], &b[5], "positions_out", F32, E * 57, 1) ||
        get_buf(o[6], &b[6], "rotations_out", F32, E * 76, 1) || get_buf(o[7], &b[7], "reach_limited", BOOL, E, 1))
        goto fail;
    a.pos_in = b[0].view.buf;
    a.quat_in = b[1].view.buf;
    a.tp = b[2].view.buf;
    a.tq = b[3].view.buf;
    a.free = free_obj != Py_None ? b[8].view.buf : NULL;
    a.offsets = b[4].view.buf;
    a.pos_out = b[5].view.buf;
    a.quat_out = b[6].view.buf;
    a.limited = b[7].view.buf;
    Py_BEGIN_ALLOW_THREADS;
    pc_upper_rows(&a, 0, E);
    Py_END_ALLOW_THREADS;
    release(b, 9);
    Py_RETURN_NONE;
fail:
    release(b, 9);
    return NULL;
}

static PyObject *py_hinge(PyObject *self, PyObject *args) {
    PyObject *o[3];
    PcHingeArgs h;
    if (!PyArg_ParseTuple(args, "OOOdddd", &o[0], &o[1], &o[2], &h.straight, &h.span, &h.flip, &h.flip_span))
        return NULL;
    Buf b[3];
    memset(b, 0, sizeof(b));
    Py_ssize_t E = get_poses(o[0], &b[0]);
    if (E < 0) goto fail;
    if (get_buf(o[1], &b[1], "rotations", F32, E * 76, 1) || get_buf(o[2], &b[2], "limbs", F64, -1, 0)) goto fail;
    h.limbs = b[2].view.len / 8 / 9;
    if (h.limbs * 9 * 8 != b[2].view.len) {
        PyErr_SetString(PyExc_ValueError, "limbs: not (L, 9)");
        goto fail;
    }
    /* A copy, checked while the GIL is held: joints in 0..18, and no joint turned by two
     * limbs (the C turns limb by limb; the reference reads every limb before writing). */
    if (h.limbs > PC_MAX_LIMBS) {
        PyErr_Format(PyExc_ValueError, "limbs: at most %d", PC_MAX_LIMBS);
        goto fail;
    }
    double spec[PC_MAX_LIMBS * 9];
    memcpy(spec, b[2].view.buf, (size_t)h.limbs * 9 * sizeof(double));
    int used[19] = {0};
    for (Py_ssize_t l = 0; l < h.limbs; l++)
        for (int k = 0; k < 3; k++) {
            double j = spec[9 * l + k];
            if (!(j >= 0 && j < 19 && j == (int)j)) {
                PyErr_SetString(PyExc_ValueError, "limbs: joints outside 0..18");
                goto fail;
            }
            if (k < 2 && used[(int)j]++) {
                PyErr_SetString(PyExc_ValueError, "limbs: a joint in two limbs");
                goto fail;
            }
        }
    h.pos = b[0].view.buf;
    h.quat = b[1].view.buf;
    h.spec = spec;
    Py_BEGIN_ALLOW_THREADS;
    pc_hinge_rows(&h, 0, E);
    Py_END_ALLOW_THREADS;
    release(b, 3);
    Py_RETURN_NONE;
fail:
    release(b, 3);
    return NULL;
}

/* --- control ---------------------------------------------------------------------- */

static PyObject *py_isa(PyObject *self, PyObject *noargs) { return PyUnicode_FromString(LEVELS[g_level].name); }

static PyObject *py_isas(PyObject *self, PyObject *noargs) {
    PyObject *out = PyList_New(0);
    for (int i = 0; out && i < N_LEVELS; i++)
        if (LEVELS[i].supported()) {
            PyObject *s = PyUnicode_FromString(LEVELS[i].name);
            if (!s || PyList_Append(out, s) != 0) {
                Py_XDECREF(s);
                Py_DECREF(out);
                return NULL;
            }
            Py_DECREF(s);
        }
    if (!out) return NULL;
    PyObject *t = PyList_AsTuple(out);
    Py_DECREF(out);
    return t;
}

static PyObject *py_set_isa(PyObject *self, PyObject *arg) {
    const char *name = PyUnicode_AsUTF8(arg);
    if (!name) return NULL;
    int i = level_index(name);
    if (i < 0) return PyErr_Format(PyExc_ValueError, "unknown ISA level %s", name);
    if (!LEVELS[i].supported()) return PyErr_Format(PyExc_ValueError, "this CPU cannot run %s", name);
    g_level = i;
    Py_RETURN_NONE;
}

static PyObject *py_precision(PyObject *self, PyObject *noargs) {
    return PyUnicode_FromString(g_bf16 ? "bf16" : "fp32");
}

static PyObject *py_set_precision(PyObject *self, PyObject *arg) {
    const char *name = PyUnicode_AsUTF8(arg);
    if (!name) return NULL;
    if (strcmp(name, "bf16") != 0 && strcmp(name, "fp32") != 0)
        return PyErr_Format(PyExc_ValueError, "unknown precision %s (bf16 or fp32)", name);
    g_bf16 = strcmp(name, "bf16") == 0;
    Py_RETURN_NONE;
}

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

static PyObject *py_encode_deltas(PyObject *self, PyObject *args) {
    PyObject *o[14];
    if (!PyArg_ParseTuple(args, "OOOOOOOOOOOOOO", &o[0], &o[1], &o[2], &o[3], &o[4], &o[5], &o[6], &o[7],
                          &o[8], &o[9], &o[10], &o[11], &o[12], &o[13]))
        return NULL;
    Buf b[14];
    memset(b, 0, sizeof(b));
    PcDeltaArgs a;
    if (get_buf(o[0], &b[0], "parents", I64, PC_REC_ITEMS, 0) || get_buf(o[1], &b[1], "seq", I64, -1, 0))
        goto fail;
    Py_ssize_t M = b[1].view.len / 8;
    if (get_buf(o[2], &b[2], "ref_seq", I64, M, 0) || get_buf(o[3], &b[3], "flags", I64, M, 0) ||
        get_buf(o[4], &b[4], "ref_items", F64, M * PC_REC_ITEMS * 4, 0) ||
        get_buf(o[5], &b[5], "step_rot", I64, M * PC_REC_ITEMS * 3, 0) ||
        get_buf(o[6], &b[6], "world", F64, M * PC_REC_ITEMS * 4, 0) ||
        get_buf(o[7], &b[7], "ref_root", I64, M * 3, 0) || get_buf(o[8], &b[8], "step_root", I64, M * 3, 0) ||
        get_buf(o[9], &b[9], "root", I64, M * 3, 0) ||
        get_buf(o[10], &b[10], "new_items", F64, M * PC_REC_ITEMS * 4, 1) ||
        get_buf(o[11], &b[11], "d_rot", I64, M * PC_REC_ITEMS * 3, 1) ||
        get_buf(o[12], &b[12], "body", "B", 1, M * PC_REC_MAX_BYTES, 1) ||
        get_buf(o[13], &b[13], "len", I64, M, 1))
        goto fail;
    /* Parents before children, checked while the GIL is held. */
    int64_t parents[PC_REC_ITEMS];
    memcpy(parents, b[0].view.buf, sizeof(parents));
    for (int j = 0; j < PC_REC_ITEMS; j++)
        if (!(j == 0 ? parents[j] == -1 : parents[j] >= 0 && parents[j] < j)) {
            PyErr_SetString(PyExc_ValueError, "parents: not a tree in joint order");
            goto fail;
        }
    a.m = M;
    a.parents = parents;
    a.seq = b[1].view.buf;
    a.ref_seq = b[2].view.buf;
    a.flags = b[3].view.buf;
    a.ref_items = b[4].view.buf;
    a.step_rot = b[5].view.buf;
    a.world = b[6].view.buf;
    a.ref_root = b[7].view.buf;
    a.step_root = b[8].view.buf;
    a.root = b[9].view.buf;
    a.new_items = b[10].view.buf;
    a.d_rot = b[11].view.buf;
    a.body = b[12].view.buf;
    a.len = b[13].view.buf;
    Py_BEGIN_ALLOW_THREADS;
    pc_encode_deltas(&a);
    Py_END_ALLOW_THREADS;
    release(b, 14);
    Py_RETURN_NONE;
fail:
    release(b, 14);
    return NULL;
}

static PyMethodDef METHODS[] = {
    {"isa", py_isa, METH_NOARGS, "The instruction-set level in use."},
    {"isas", py_isas, METH_NOARGS, "Levels this CPU runs, best first."},
    {"set_isa", py_set_isa, METH_O, "Use this level (one from isas())."},
    {"precision", py_precision, METH_NOARGS, "The GRU gates' arithmetic: bf16 or fp32."},
    {"set_precision", py_set_precision, METH_O, "bf16 or fp32 gates, on any level."},
    {"set_threads", py_set_threads, METH_O, "Threads for the kernels (the caller is one)."},
    {"threads", py_threads, METH_NOARGS, "Threads the kernels use."},
    {"pool_stats", py_pool_stats, METH_NOARGS, "Tiles each pool thread has run (the caller first)."},
    {"pack_decoder", py_pack_decoder, METH_VARARGS, "Pack decoder weights."},
    {"pack_pool", py_pack_pool, METH_VARARGS, "Pack skeleton and anomaly-AE weights."},
    {"decode", py_decode, METH_VARARGS, "One decoder step for R rows."},
    {"pool", py_pool, METH_VARARGS, "FK, contact IK and anomaly error of R rows."},
    {"emit", py_emit, METH_VARARGS, "The shown poses: FK, display IK, quaternions."},
    {"upper_body", py_upper_body, METH_VARARGS, "Head and hands onto their trackers (upper_ik)."},
    {"hinge", py_hinge, METH_VARARGS, "Limbs onto their hinges, in place (hinge)."},
    {"encode_deltas", py_encode_deltas, METH_VARARGS, "Protocol v2 delta records (records.encode_deltas)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef MODULE = {PyModuleDef_HEAD_INIT, "_native", "posecast's native SSI kernels.", -1,
                                    METHODS};

PyMODINIT_FUNC PyInit__native(void) {
    /* The best level the CPU runs, capped by POSECAST_NATIVE_ISA; bf16 gates where that
     * level has the bf16 instructions, fp32 elsewhere, unless POSECAST_NATIVE_PRECISION
     * names one (bf16 on a level without the instructions: the same arithmetic in plain
     * vector code). The bf16 figures on the validation split: docs/engine.md. */
    int cap = 0;
    const char *forced = getenv("POSECAST_NATIVE_ISA");
    if (forced && *forced) {
        cap = level_index(forced);
        if (cap < 0) {
            PyErr_Format(PyExc_ImportError, "POSECAST_NATIVE_ISA=%s is not one of avx512bf16, avx512f, avx2, generic",
                         forced);
            return NULL;
        }
    }
    g_level = best_level(cap);
    g_bf16 = strcmp(LEVELS[g_level].name, "avx512bf16") == 0;
    const char *prec = getenv("POSECAST_NATIVE_PRECISION");
    if (prec && *prec) {
        if (strcmp(prec, "bf16") != 0 && strcmp(prec, "fp32") != 0) {
            PyErr_Format(PyExc_ImportError, "POSECAST_NATIVE_PRECISION=%s is not one of bf16, fp32", prec);
            return NULL;
        }
        g_bf16 = strcmp(prec, "bf16") == 0;
    }
    if (ensure_threads(1) != 0) return PyErr_NoMemory();
    pthread_atfork(NULL, NULL, after_fork_child);
    return PyModule_Create(&MODULE);
}

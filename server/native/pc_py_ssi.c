/* The SSI kernels' calls, on all R rows of a tick: decode (the decoder step), pool
 * (FK, contact IK and anomaly error) and emit (the shown poses). Each checks its
 * arrays with the GIL held, then releases it and runs the level's kernel
 * (pc_level_kernels) over the rows' tiles on the thread pool.
 */
#include "pc_module.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

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
    PcDecoderBox *box = PyCapsule_GetPointer(cap, PC_DECODER_CAPSULE);
    if (!box) return NULL;
    const PcDecoder *d = &box->d;
    PcBuf b[7];
    memset(b, 0, sizeof(b));
    if (group < 1) {
        PyErr_SetString(PyExc_ValueError, "group must be >= 1");
        return NULL;
    }
    if (pc_get_buf(o[0], &b[0], "features", F32, -1, 0)) goto fail;
    Py_ssize_t G = b[0].view.len / 4 / d->F, R = G * group;
    if (G * d->F * 4 != b[0].view.len) {
        PyErr_SetString(PyExc_ValueError, "features: not (G, F)");
        goto fail;
    }
    if (pc_get_buf(o[1], &b[1], "cache", F32, R * d->H, 0) || pc_get_buf(o[2], &b[2], "h", F32, R * d->H, 0) ||
        pc_get_buf(o[3], &b[3], "rotations", F32, R * d->n_rot, 1) ||
        pc_get_buf(o[5], &b[5], "contacts", F32, R * 2, 1) ||
        pc_get_buf(o[6], &b[6], "h_out", F32, R * d->H, 1))
        goto fail;
    if (d->n_root) {
        if (o[4] == Py_None) {
            PyErr_SetString(PyExc_ValueError, "root: this model predicts the pelvis");
            goto fail;
        }
        if (pc_get_buf(o[4], &b[4], "root", F32, R * d->n_root, 1)) goto fail;
    }
    float *xproj = NULL;
    if (G > 0 && posix_memalign((void **)&xproj, PC_ALIGN, (size_t)G * d->H * 4) != 0) {
        PyErr_NoMemory();
        goto fail;
    }
    DecodeCtx c = {pc_level_kernels(), d, {xproj, group, b[1].view.buf, b[2].view.buf, b[3].view.buf,
                                          d->n_root ? b[4].view.buf : NULL, b[5].view.buf, b[6].view.buf,
                                          pc_bf16_gates()}};
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
    if (R > 0) pc_parallel_rows(decode_fn, &c, R);
    Py_END_ALLOW_THREADS;
    free(xproj);
    pc_release(b, 7);
    Py_RETURN_NONE;
fail:
    pc_release(b, 7);
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
static int get_pool_bufs(PyObject **o, PcBuf *b, Py_ssize_t R, Py_ssize_t group, int release_frames,
                         double max_drift, int emit, PcPoolArgs *a) {
    Py_ssize_t G = R / group;
    if (pc_get_buf(o[1], &b[1], "contacts", F32, R * 2, 0) ||
        pc_get_buf(o[2], &b[2], "root_mat", F32, G * 9, 0) ||
        pc_get_buf(o[3], &b[3], "root_pos", F32, G * 3, 0) ||
        pc_get_buf(o[4], &b[4], "locked", BOOL, R * 2, 1) ||
        pc_get_buf(o[5], &b[5], "lock_pos", F64, R * 6, 1) ||
        pc_get_buf(o[6], &b[6], "release", I64, R * 2, 1) ||
        pc_get_buf(o[7], &b[7], "suppressed", BOOL, R * 2, 1) ||
        pc_get_buf(o[8], &b[8], emit ? "positions" : "world_out", F32, R * 57, 1) ||
        (emit ? pc_get_buf(o[9], &b[9], "rotations_out", F32, R * 76, 1)
              : pc_get_buf(o[9], &b[9], "scores", F64, R, 1)))
        return -1;
    PcPoolArgs args = {b[0].view.buf, b[1].view.buf, b[2].view.buf, b[3].view.buf, group, b[4].view.buf,
                       b[7].view.buf, b[5].view.buf, b[6].view.buf, release_frames, max_drift, b[8].view.buf,
                       emit ? NULL : b[9].view.buf, emit ? b[9].view.buf : NULL};
    *a = args;
    return 0;
}

/* The rotations (R, 108) in b[0]; R, or -1 with the error set. */
static Py_ssize_t get_rotations(PyObject *o, PcBuf *b, Py_ssize_t group) {
    if (pc_get_buf(o, b, "rotations", F32, -1, 0)) return -1;
    Py_ssize_t R = b->view.len / 4 / 108;
    if (R * 108 * 4 != b->view.len || R % group) {
        PyErr_SetString(PyExc_ValueError, "rotations: not (R, 108) with R a multiple of group");
        return -1;
    }
    return R;
}

static PyObject *run_pool(PyObject *cap, PyObject **o, Py_ssize_t group, int release_frames, double max_drift,
                          int emit) {
    PcPoolBox *box = PyCapsule_GetPointer(cap, PC_POOL_CAPSULE);
    if (!box) return NULL;
    if (group < 1) {
        PyErr_SetString(PyExc_ValueError, "group must be >= 1");
        return NULL;
    }
    PcBuf b[10];
    memset(b, 0, sizeof(b));
    PoolCtx c = {pc_level_kernels(), &box->p, {0}};
    Py_ssize_t R = get_rotations(o[0], &b[0], group);
    if (R < 0 || get_pool_bufs(o, b, R, group, release_frames, max_drift, emit, &c.a)) {
        pc_release(b, 10);
        return NULL;
    }
    Py_BEGIN_ALLOW_THREADS;
    if (R > 0) pc_parallel_rows(emit ? emit_fn : pool_fn, &c, R);
    Py_END_ALLOW_THREADS;
    pc_release(b, 10);
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

PyMethodDef pc_ssi_methods[] = {
    {"decode", py_decode, METH_VARARGS, "One decoder step for R rows."},
    {"pool", py_pool, METH_VARARGS, "FK, contact IK and anomaly error of R rows."},
    {"emit", py_emit, METH_VARARGS, "The shown poses: FK, display IK, quaternions."},
    {NULL, NULL, 0, NULL},
};

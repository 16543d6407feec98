/* The weights packed for the kernels, once per model at load: pack_decoder and
 * pack_pool copy them into 64-byte aligned blocks laid out as the kernels read them
 * (the head padded to PC_HEADW columns, each AE layer to a multiple of 64, the GRU
 * products also as bf16 pairs) and hand them back as capsules for decode, pool and
 * emit (pc_py_ssi.c).
 */
#include "pc_module.h"

#include <stdint.h>
#include <stdlib.h>
#include <string.h>

static void free_decoder(PyObject *cap) {
    PcDecoderBox *b = PyCapsule_GetPointer(cap, PC_DECODER_CAPSULE);
    if (b) {
        free(b->mem);
        free(b);
    }
}

static void free_pool(PyObject *cap) {
    PcPoolBox *b = PyCapsule_GetPointer(cap, PC_POOL_CAPSULE);
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
    PcBuf b[10];
    memset(b, 0, sizeof(b));
    const char *names[10] = {"mean", "inv_std", "wx", "bfc", "wih", "bih", "whh", "bhh", "whead", "bhead"};
    const Py_ssize_t counts[10] = {F, F, (Py_ssize_t)F * H, H, (Py_ssize_t)H * 3 * H, 3 * H,
                                   (Py_ssize_t)H * 3 * H, 3 * H, (Py_ssize_t)H * K, K};
    for (int i = 0; i < 10; i++)
        if (pc_get_buf(o[i], &b[i], names[i], F32, counts[i], 0) != 0) {
            pc_release(b, 10);
            return NULL;
        }
    size_t floats = 2 * F + F * H + H + 2 * 3 * H * H + 2 * 3 * H + H * PC_HEADW + PC_HEADW +
                    3 * H * H /* bf16 pairs: 2 x (H/2 x 3H) uint32 */ + 16 * 64;
    PcDecoderBox *box = calloc(1, sizeof(PcDecoderBox));
    void *mem = NULL;
    if (!box || posix_memalign(&mem, PC_ALIGN, floats * 4 + 64 * PC_ALIGN) != 0) {
        free(box);
        pc_release(b, 10);
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
    pc_release(b, 10);
    return PyCapsule_New(box, PC_DECODER_CAPSULE, free_decoder);
}

static PyObject *py_pack_pool(PyObject *self, PyObject *args) {
    PyObject *o_off, *o_mean, *o_std, *layers;
    if (!PyArg_ParseTuple(args, "OOOO", &o_off, &o_mean, &o_std, &layers)) return NULL;
    if (!PyList_Check(layers) || PyList_GET_SIZE(layers) != PC_AE_LAYERS) {
        PyErr_Format(PyExc_ValueError, "layers: a list of %d (w, b) pairs", PC_AE_LAYERS);
        return NULL;
    }
    PcBuf b[3];
    memset(b, 0, sizeof(b));
    if (pc_get_buf(o_off, &b[0], "offsets", F32, PC_J * 3, 0) ||
        pc_get_buf(o_mean, &b[1], "mean", F32, PC_J * 3, 0) ||
        pc_get_buf(o_std, &b[2], "inv_std", F32, PC_J * 3, 0)) {
        pc_release(b, 3);
        return NULL;
    }
    PcPoolBox *box = calloc(1, sizeof(PcPoolBox));
    size_t bytes = (size_t)PC_AE_LAYERS * (PC_AE_MAXW * PC_AE_MAXW + PC_AE_MAXW) * 4 + 64 * PC_ALIGN;
    void *mem = NULL;
    if (!box || posix_memalign(&mem, PC_ALIGN, bytes) != 0) {
        free(box);
        pc_release(b, 3);
        return PyErr_NoMemory();
    }
    box->mem = mem;
    Arena ar = {mem, 0, bytes};
    PcPool *p = &box->p;
    memcpy(p->offsets, b[0].view.buf, sizeof(p->offsets));
    memcpy(p->mean, b[1].view.buf, sizeof(p->mean));
    memcpy(p->inv_std, b[2].view.buf, sizeof(p->inv_std));
    pc_release(b, 3);
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
        PcBuf lb[2];
        memset(lb, 0, sizeof(lb));
        if (pc_get_buf(ow, &lb[0], "layer weight", F32, (Py_ssize_t)k * n, 0) ||
            pc_get_buf(ob, &lb[1], "layer bias", F32, n, 0)) {
            pc_release(lb, 2);
            goto fail;
        }
        PcLayer *L = &p->layers[l];
        L->k = k, L->n = n, L->np = (n + 63) / 64 * 64;
        L->w = take(&ar, (size_t)k * L->np), L->b = take(&ar, L->np);
        const float *w = lb[0].view.buf;
        for (int i = 0; i < k; i++) memcpy(L->w + (size_t)i * L->np, w + (size_t)i * n, n * 4);
        memcpy(L->b, lb[1].view.buf, n * 4);
        pc_release(lb, 2);
        k_expect = n;
    }
    return PyCapsule_New(box, PC_POOL_CAPSULE, free_pool);
fail:
    free(box->mem);
    free(box);
    return NULL;
}

PyMethodDef pc_pack_methods[] = {
    {"pack_decoder", py_pack_decoder, METH_VARARGS, "Pack decoder weights."},
    {"pack_pool", py_pack_pool, METH_VARARGS, "Pack skeleton and anomaly-AE weights."},
    {NULL, NULL, 0, NULL},
};
